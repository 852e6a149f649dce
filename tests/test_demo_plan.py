"""The demo's plan: which runs it trains, for how long, and the shipped runs that stand in for the
baselines that do not fit its budget (no training here: the jobs are planned, not run)."""

from __future__ import annotations

from pathlib import Path

import pytest

from edofproj.application import demo
from edofproj.application.durations import FULL_BUDGET_MIN, FULL_DURATION, QUICK_DURATION
from edofproj.cli import build_parser
from edofproj.config import load_config
from edofproj.runs import load_run


def _jobs(tmp_path, **kwargs):
    cfg = load_config("cpu", list(demo.FULL.overrides))
    return demo.demo_jobs(tmp_path, demo.FULL, cfg, None, [], **kwargs)


def test_ours_trains_the_demo_steps_and_the_baselines_the_preset_steps(tmp_path):
    jobs = {job.method: job for job in _jobs(tmp_path)}
    assert (
        jobs["doe+net"].steps == demo.OURS_DEMO_STEPS
        and f"train.steps={demo.OURS_DEMO_STEPS}" in jobs["doe+net"].overrides
    )
    preset_steps = load_config("cpu").train.steps
    for method in ("lens+net", "axicon+net", "cubic+net", "lens+onlineprodeb"):
        assert jobs[method].steps == preset_steps
    assert [m for m, j in jobs.items() if j.required] == ["doe+net", "lens+net"]


def test_a_user_step_count_applies_to_every_run(tmp_path):
    cfg = load_config("cpu", ["train.steps=50"])
    jobs = demo.demo_jobs(tmp_path, demo.FULL, cfg, None, ["train.steps=50"])
    assert {job.steps for job in jobs} == {50}


def test_retrain_baselines_makes_every_baseline_required(tmp_path):
    assert all(job.required for job in _jobs(tmp_path, retrain_baselines=True))


def test_a_skipped_baseline_is_replaced_by_its_shipped_run_of_the_same_recipe(tmp_path):
    jobs = _jobs(tmp_path)
    by_method = {job.method: job for job in jobs}
    for method in ("axicon+net", "cubic+net", "lens+onlineprodeb"):
        by_method[method].status = "skipped"
        by_method[method].note = "not trained: predicted 5:00 (min:s) would end after the time budget"
    demo.use_builtin_baselines(jobs, ["evaluation.depths_mm=[300,800]"], "cpu")
    for method in ("axicon+net", "cubic+net", "lens+onlineprodeb"):  # shipped, trained with the preset as it is
        job = by_method[method]
        assert job.status == "built-in", job.note
        assert f"builtin:{demo.BUILTIN_BASELINES[method]}" in job.note and "--retrain-baselines" in job.note
        assert load_run(job.run_dir).step == load_config("cpu").train.steps
        assert load_run(job.run_dir).cfg.evaluation.depths_mm == [300.0, 800.0]  # the demo's evaluation keys


def test_a_shipped_run_of_another_recipe_is_not_used(tmp_path, monkeypatch):
    monkeypatch.setitem(demo.BUILTIN_BASELINES, "cubic+net", "cpu-doe-net")  # a doe+net run, not a cubic one
    jobs = _jobs(tmp_path)
    cubic = next(job for job in jobs if job.method == "cubic+net")
    cubic.status, cubic.note = "skipped", "not trained: predicted 5:00 (min:s) would end after the time budget"
    demo.use_builtin_baselines(jobs, [], "cpu")
    assert cubic.status == "skipped"
    assert "its shipped run builtin:cpu-doe-net was trained with another recipe: " in cubic.note
    assert not Path(cubic.run_dir).exists()


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
