"""The demo's plan: which runs it trains, for how long, and the shipped runs that stand in for the
baselines that do not fit its budget (no training here: the jobs are planned, not run)."""

from __future__ import annotations

from pathlib import Path

import pytest

from edofproj.application import demo
from edofproj.application.durations import FULL_BUDGET_MIN, FULL_DURATION, QUICK_DURATION
from edofproj.cli import build_parser
from edofproj.config import load_config
from edofproj.methods.builder import require_trained_run
from edofproj.runs import load_run, saved_config
from edofproj.training.phases import training_phases


def _jobs(tmp_path, preset="cpu", **kwargs):
    cfg = load_config(preset, list(demo.FULL.overrides))
    return demo.demo_jobs(tmp_path, demo.FULL, cfg, None, [], **kwargs)


def test_ours_trains_two_phases_and_every_u_net_baseline_the_refit_phase_alone(tmp_path):
    preset = load_config("cpu").train
    jobs = {job.method: job for job in _jobs(tmp_path)}
    assert jobs["doe+net"].steps == preset.steps + preset.refit_steps
    for method in ("lens+net", "axicon+net", "cubic+net"):  # the same network as doe+net's final one, trained alike
        job = jobs[method]
        run = load_config("cpu", job.overrides)
        assert job.steps == preset.refit_steps and [p.name for p in training_phases(run)] == ["refit"], method
    onlineprodeb = jobs["lens+onlineprodeb"]  # another architecture: its own recipe, one phase
    assert onlineprodeb.steps == demo.OWN_RECIPE_STEPS["lens+onlineprodeb"] != preset.steps
    assert [p.name for p in training_phases(load_config("cpu", onlineprodeb.overrides))] == ["joint"]
    assert [m for m, j in jobs.items() if j.required] == ["doe+net", "lens+net"]
    assert demo.steps_sentence(list(jobs.values())) == (
        "2000 training steps for doe+net; 1000 for lens+net, axicon+net, cubic+net; 1800 for lens+onlineprodeb"
    )
    # doe+net's joint phase simulates PSFs (dearer), its refit phase costs as lens+net
    assert (
        1.0 < jobs["doe+net"].relative_cost < demo.job_costs(load_config("cpu", ["train.refit_steps=0"]))["doe+net"][0]
    )


def test_the_realtime_preset_trains_every_run_in_one_phase_of_its_steps(tmp_path):
    jobs = {job.method: job for job in _jobs(tmp_path, "cpu-realtime")}
    assert {jobs[m].steps for m in ("doe+net", "lens+net", "axicon+net", "cubic+net")} == {2400}


def test_a_quick_demo_caps_the_refit_phase_only_where_there_is_one(tmp_path):
    cfg = load_config("cpu", list(demo.QUICK.overrides))
    jobs = {job.method: job for job in demo.demo_jobs(tmp_path, demo.QUICK, cfg, None, [])}
    assert (jobs["doe+net"].steps, jobs["lens+net"].steps, jobs["lens+onlineprodeb"].steps) == (24, 12, 12)
    assert load_config("cpu", jobs["lens+onlineprodeb"].overrides).train.refit_steps == 0


def test_a_pretrained_demo_trains_the_u_net_baselines_the_demo_steps(tmp_path, monkeypatch):
    """With ``--pretrained`` the baselines train with the pretrained run's configuration (its network, one
    phase) for :data:`PRETRAINED_BASELINE_CROPS` crops (so that the shipped runs of its recipe still stand for
    them): the reference model's refit phase in batches of 16, 600 steps, its warm-up the recipe's fraction."""
    seen = {}

    def plan(self):
        seen["jobs"] = {job.method: job for job in self.jobs}
        raise KeyboardInterrupt  # only the plan is under test

    monkeypatch.setattr(demo.ParallelTrainer, "plan", plan)
    with pytest.raises(KeyboardInterrupt):
        demo.run_demo(tmp_path / "d", pretrained="builtin:cpu-doe-net")
    jobs = seen["jobs"]
    assert "doe+net" not in jobs
    assert {jobs[m].steps for m in ("lens+net", "axicon+net", "cubic+net")} == {600}
    reference = saved_config(require_trained_run("builtin:cpu-doe-net")).train
    assert 600 * reference.refit_batch_size == demo.PRETRAINED_BASELINE_CROPS
    refit = load_config(str(require_trained_run("builtin:cpu-doe-net") / "config.yaml"), jobs["lens+net"].overrides)
    assert refit.train.refit_warmup_steps == reference.refit_warmup_steps * 600 // reference.refit_steps
    assert jobs["lens+onlineprodeb"].steps == demo.OWN_RECIPE_STEPS["lens+onlineprodeb"]
    # the preset's tuned elements, which the pretrained (learned-DOE) run never reads: its baselines train with
    # them, and the copy that stands for doe+net builds its classic linear baselines with them
    preset = load_config("cpu").doe
    trained_with = load_config(
        str(require_trained_run("builtin:cpu-doe-net") / "config.yaml"), jobs["cubic+net"].overrides
    )
    copied = saved_config(tmp_path / "d" / demo.OURS_RUN_DIR)
    for doe in (trained_with.doe, copied.doe):
        assert (doe.cubic_waves, doe.axicon_near_mm, doe.axicon_far_mm) == (
            preset.cubic_waves,
            preset.axicon_near_mm,
            preset.axicon_far_mm,
        )
    assert copied.doe.kind == "mlp" and copied.net == saved_config(require_trained_run("builtin:cpu-doe-net")).net


def test_a_user_step_count_sets_the_joint_phase_and_onlineprodebs_steps(tmp_path):
    cfg = load_config("cpu", ["train.steps=50"])
    jobs = {job.method: job for job in demo.demo_jobs(tmp_path, demo.FULL, cfg, None, ["train.steps=50"])}
    refit = cfg.train.refit_steps
    assert (jobs["doe+net"].steps, jobs["lens+net"].steps, jobs["lens+onlineprodeb"].steps) == (50 + refit, refit, 50)


def test_retrain_baselines_makes_every_baseline_required(tmp_path):
    assert all(job.required for job in _jobs(tmp_path, retrain_baselines=True))


@pytest.mark.parametrize(
    "preset, method, shipped",
    [
        ("cpu", "axicon+net", "demo-refit-axicon-net"),
        ("cpu", "cubic+net", "demo-refit-cubic-net"),
        ("cpu", "lens+onlineprodeb", "demo-lens-onlineprodeb"),
        ("cpu-realtime", "axicon+net", "demo-realtime-axicon-net"),
        ("cpu-realtime", "cubic+net", "demo-realtime-cubic-net"),
        ("cpu-realtime", "lens+onlineprodeb", "demo-realtime-lens-onlineprodeb"),  # its PSFs in float32
    ],
)
def test_a_skipped_baseline_is_replaced_by_its_shipped_run_of_the_same_recipe(tmp_path, preset, method, shipped):
    jobs = _jobs(tmp_path, preset)
    job = next(job for job in jobs if job.method == method)
    job.status = "skipped"
    job.note = "not trained: predicted 5:00 (min:s) would end after the time budget"
    demo.use_builtin_baselines(jobs, ["evaluation.depths_mm=[300,800]"], preset)
    assert job.status == "built-in", job.note  # shipped, trained with the preset as it is
    assert f"shipped run builtin:{shipped} (" in job.note and "--retrain-baselines" in job.note
    assert load_run(job.run_dir).step == job.steps
    assert load_run(job.run_dir).cfg.evaluation.depths_mm == [300.0, 800.0]  # the demo's evaluation keys


def test_a_one_phase_pretrained_runs_baselines_see_as_many_crops_in_its_batch():
    unet = saved_config(require_trained_run("builtin:cpu-doe-unet"))
    assert demo.pretrained_baseline_overrides(unet) == [
        f"train.steps={demo.PRETRAINED_BASELINE_CROPS // unet.train.batch_size}"
    ]


@pytest.mark.parametrize(
    "method, shipped",
    [
        ("axicon+net", "demo-axicon-net"),
        ("cubic+net", "demo-cubic-net"),
        ("lens+onlineprodeb", "demo-lens-onlineprodeb"),
    ],
)
def test_a_pretrained_demos_skipped_baseline_is_its_shipped_run_of_the_reference_recipe(
    tmp_path, monkeypatch, method, shipped
):
    """``demo --pretrained`` trains a baseline as the reference model's refit phase for
    PRETRAINED_BASELINE_CROPS crops (OnlineProDeb: its own one-phase recipe, which reads neither the refit phase's
    keys nor its network); the shipped run of that recipe stands for it when the budget cannot train it."""
    seen = {}

    def plan(self):
        seen["jobs"] = list(self.jobs)
        raise KeyboardInterrupt  # only the plan is under test

    monkeypatch.setattr(demo.ParallelTrainer, "plan", plan)
    with pytest.raises(KeyboardInterrupt):
        demo.run_demo(tmp_path / "d", pretrained="builtin:cpu-doe-net")
    job = next(job for job in seen["jobs"] if job.method == method)
    # the refit phase alone (a fixed element has no joint phase); OnlineProDeb its own steps
    assert job.steps == demo.OWN_RECIPE_STEPS.get(method, 600)
    job.status, job.note = "skipped", "not trained: predicted 9:00 (min:s) would end after the time budget"
    demo.use_builtin_baselines(seen["jobs"], [], str(require_trained_run("builtin:cpu-doe-net") / "config.yaml"))
    assert job.status == "built-in", job.note
    assert f"shipped run builtin:{shipped} (" in job.note
    assert load_run(job.run_dir).step == job.steps


def test_a_shipped_run_of_another_recipe_is_not_used(tmp_path, monkeypatch):
    monkeypatch.setitem(demo.BUILTIN_BASELINES, "cubic+net", ("cpu-doe-net",))  # a doe+net run, not a cubic one
    jobs = _jobs(tmp_path)
    cubic = next(job for job in jobs if job.method == "cubic+net")
    cubic.status, cubic.note = "skipped", "not trained: predicted 5:00 (min:s) would end after the time budget"
    demo.use_builtin_baselines(jobs, [], "cpu")
    assert cubic.status == "skipped"
    assert "its shipped run builtin:cpu-doe-net was trained with another recipe: " in cubic.note
    assert not Path(cubic.run_dir).exists()


def test_recipe_difference_ignores_the_classic_keys_that_neither_runs_doe_reads():
    old_elements = ["doe.cubic_waves=20", "doe.axicon_near_mm=300", "doe.axicon_far_mm=800"]
    for kind in ("lens", "mlp", "multifocal"):  # never read the cubic plate's or the axicon's keys
        shipped = load_config("cpu", [f"doe.kind={kind}", *old_elements])
        assert demo.recipe_difference(shipped, load_config("cpu", [f"doe.kind={kind}"])) is None, kind
    cubic = load_config("cpu", ["doe.kind=cubic", *old_elements])  # a cubic run reads its strength
    assert demo.recipe_difference(cubic, load_config("cpu", ["doe.kind=cubic"])) == (
        "doe.cubic_waves=20.0 (the demo: 5.0)"
    )
    axicon = load_config("cpu", ["doe.kind=axicon", "doe.cubic_waves=20"])  # ... an axicon its focal line only
    assert demo.recipe_difference(axicon, load_config("cpu", ["doe.kind=axicon"])) is None
    assert demo.recipe_difference(
        load_config("cpu", ["doe.kind=axicon", *old_elements]), load_config("cpu", ["doe.kind=axicon"])
    ) == ("doe.axicon_far_mm=800.0 (the demo: 530.0)")
    multifocal = load_config("cpu", ["doe.kind=multifocal", "doe.multifocal_foci_mm=[300,800]"])
    assert demo.recipe_difference(multifocal, load_config("cpu", ["doe.kind=multifocal"])).startswith(
        "doe.multifocal_foci_mm="
    )
    lens = load_config("cpu", ["doe.kind=lens"])  # another kind: the kind itself differs
    assert demo.recipe_difference(lens, load_config("cpu", ["doe.kind=cubic"])) == "doe.kind='lens' (the demo: 'cubic')"


def test_recipe_difference_ignores_bookkeeping_and_names_the_first_real_difference():
    a = load_config("cpu", ["train.checkpoint_every=7", "train.threads=1", "evaluation.depths_mm=[300]"])
    assert demo.recipe_difference(a, load_config("cpu")) is None
    b = load_config("cpu", ["train.lr_net=0.5"])
    assert demo.recipe_difference(b, load_config("cpu")) == "train.lr_net=0.5 (the demo: 0.001)"


def test_every_help_text_states_the_same_durations():
    parser = build_parser()
    top = parser.format_help()
    demo_parser = next(
        action.choices["demo"]
        for action in parser._actions
        if getattr(action, "choices", None) and "demo" in action.choices
    )
    demo_help = demo_parser.format_help()
    for text in (top, demo_help):
        assert FULL_DURATION in " ".join(text.split()) and QUICK_DURATION in " ".join(text.split())
    assert f"default {FULL_BUDGET_MIN}," in " ".join(demo_help.split())
    readme = (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8")
    assert FULL_DURATION in readme and f"{FULL_BUDGET_MIN}-minute budget" in readme


@pytest.mark.parametrize("settings", [demo.FULL, demo.QUICK])
def test_the_report_budget_is_the_stated_one(settings):
    minutes = FULL_BUDGET_MIN if settings is demo.FULL else demo.QUICK_BUDGET_MIN
    assert settings.budget_s == minutes * 60


@pytest.mark.parametrize("preset", ["cpu-realtime", "realtime", "paper"])
def test_every_preset_scores_the_tuned_classic_elements(preset):
    """Whatever a preset trains, `evaluate` of its runs scores the classic elements as tuned for this
    projector and 300-800 mm (the cpu preset's values): a 20-wave plate or a 300-800 mm axicon would be
    the untuned rivals the results no longer compare against."""
    tuned, doe = load_config("cpu").doe, load_config(preset).doe
    assert (doe.cubic_waves, doe.axicon_near_mm, doe.axicon_far_mm, doe.multifocal_foci_mm) == (
        tuned.cubic_waves,
        tuned.axicon_near_mm,
        tuned.axicon_far_mm,
        tuned.multifocal_foci_mm,
    )


def test_recipe_difference_counts_only_what_a_phase_reads():
    one_phase = ["train.refit_steps=0"]
    # a run in one phase never reads the refit phase's network or keys
    unread = load_config("cpu", [*one_phase, "refit_net.architecture=multirate", "train.refit_lr_net=0.5"])
    assert demo.recipe_difference(unread, load_config("cpu", one_phase)) is None
    # a run in two phases reads them in its refit phase; a difference is named by the key a user sets
    refit = load_config("cpu", ["refit_net.architecture=multirate"])
    assert demo.recipe_difference(refit, load_config("cpu")) == (
        "refit_net.architecture='multirate' (the demo: net.architecture='unet')"
    )
    shorter = load_config("cpu", ["train.refit_steps=500"])
    assert demo.recipe_difference(shorter, load_config("cpu")) == "train.refit_steps=500 (the demo: 1000)"
    cubic = ["doe.kind=cubic"]  # a fixed element: the refit phase alone
    faster = load_config("cpu", [*cubic, "train.refit_lr_net=0.5"])
    assert demo.recipe_difference(faster, load_config("cpu", cubic)) == "train.refit_lr_net=0.5 (the demo: 0.003)"
    assert demo.recipe_difference(load_config("cpu", one_phase), load_config("cpu")) == (
        "phases=joint (the demo: joint+refit)"
    )
