"""The phases of a training run: the DOE and a network jointly, then a fresh network for the found DOE.

A run with ``train.refit_steps = R > 0`` and a learned DOE (``doe.kind`` mlp or free, ``train.train_doe``)
trains in two phases, one after the other in the same run directory, with one step count, one log and
one checkpoint series:

1. **joint**, steps ``1 .. S`` (``S = train.steps``): the DOE and a network together (:mod:`.trainer`);
   the network's job here is to shape the DOE. At its end the DOE is fabricated to ``doe.npz``.
2. **refit**, steps ``S + 1 .. S + R``: the DOE of ``doe.npz`` frozen (its PSFs read from a table, as
   for any fixed DOE), a fresh network trained for it at ``train.refit_lr_net`` with a warm-up of
   ``train.refit_warmup_steps``, on crops colour-transformed at ``train.refit_colour_augment``. Its
   network (the ``refit_net`` section's where the config has one, else ``net``'s) is the run's.

A network that trains with a DOE that still moves has to follow it, and a learning rate high enough to
train a small network quickly lets it pull the DOE off course at the far end of the depth range; once
the DOE is fixed, the network can train fast. A run whose DOE does not train has only the refit phase:
the network of a fixed or classic element (the baselines) is trained exactly as a learned DOE's final
network. With ``R = 0`` (the default) a run is one phase of ``S`` steps, as it always was.

Inside a phase, steps count from 1 (the learning-rate schedule, the training crops and depths drawn
from ``(train.seed, step)``); the run's files count ``offset + step``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..config import Config

JOINT = "joint"
REFIT = "refit"


@dataclass(frozen=True)
class Phase:
    """One phase: its name, its configuration (``train.steps`` = the phase's steps), the run's step
    before its first, and whether its DOE is the one the run's first phase fabricated (``doe.npz``)."""

    name: str
    cfg: Config
    offset: int
    doe_from_run: bool

    @property
    def end(self) -> int:
        """The run's step after the phase's last."""
        return self.offset + self.cfg.train.steps


def refit_config(cfg: Config) -> Config:
    """The configuration of the refit phase: the DOE frozen, ``train.refit_steps`` steps of a fresh
    network (``refit_net``, else ``net``) at ``train.refit_lr_net`` after ``train.refit_warmup_steps``,
    colour augmentation ``train.refit_colour_augment``, batches of ``train.refit_batch_size`` (0: as the
    first phase's); the rest as ``cfg``. :data:`REFIT_KEY_SOURCES` and :func:`run_key` say the same mapping
    key by key (keep the three together)."""
    train = dataclasses.replace(
        cfg.train,
        steps=cfg.train.refit_steps,
        lr_net=cfg.train.refit_lr_net,
        warmup_steps=cfg.train.refit_warmup_steps,
        batch_size=cfg.train.refit_batch_size or cfg.train.batch_size,
        train_doe=False,
        refit_steps=0,
        refit_batch_size=0,
    )
    data = dataclasses.replace(cfg.data, colour_augment=cfg.train.refit_colour_augment)
    net = cfg.refit_net if cfg.refit_net is not None else cfg.net
    return dataclasses.replace(cfg, net=net, refit_net=None, train=train, data=data)


#: The configuration keys of the refit phase that :func:`refit_config` takes from other keys of the run's
#: configuration: ``{key in the phase: key in the run}`` (``net.*`` comes from ``refit_net.*`` where the run has
#: that section; ``train.batch_size`` from ``train.refit_batch_size`` where that is set).
REFIT_KEY_SOURCES = {
    "train.steps": "train.refit_steps",
    "train.lr_net": "train.refit_lr_net",
    "train.warmup_steps": "train.refit_warmup_steps",
    "data.colour_augment": "train.refit_colour_augment",
}


def run_key(phase: Phase, key: str, cfg: Config) -> str:
    """The key of the run's configuration ``cfg`` that sets ``key`` of ``phase``'s configuration (the same key
    but in a refit phase, :data:`REFIT_KEY_SOURCES`): what a user writes to change it."""
    if phase.name != REFIT:
        return key
    if key.startswith("net.") and cfg.refit_net is not None:
        return "refit_net." + key[len("net.") :]
    if key == "train.batch_size" and cfg.train.refit_batch_size:
        return "train.refit_batch_size"
    return REFIT_KEY_SOURCES.get(key, key)


def training_phases(cfg: Config) -> list[Phase]:
    """The phases of a run with configuration ``cfg`` (module docstring), in order."""
    if cfg.train.refit_steps <= 0:
        return [Phase(JOINT, cfg, 0, False)]
    refit = refit_config(cfg)
    if not cfg.doe_learns():
        return [Phase(REFIT, refit, 0, False)]
    joint = dataclasses.replace(cfg, refit_net=None, train=dataclasses.replace(cfg.train, refit_steps=0))
    return [Phase(JOINT, joint, 0, False), Phase(REFIT, refit, cfg.train.steps, True)]


def total_steps(cfg: Config) -> int:
    """Optimizer steps of a whole run: the sum over its phases."""
    return training_phases(cfg)[-1].end
