"""Where a command may write: never over, around or into what it reads.

A command's output (a file, or a folder that ``--overwrite`` replaces as a whole) must not destroy
its inputs. :func:`refuse_output_over_inputs` is the one rule every command applies before any
work, with paths compared after resolving symlinks, ``..`` and relative paths
(:meth:`pathlib.Path.resolve`; an existing file reached by two names, a hard link, is one file:
:func:`os.path.samefile`). For an output ``O`` and each input ``I`` (a file or folder read):

* ``O`` *is* ``I``: writing ``O`` replaces the input;
* ``O`` *contains* ``I`` (``I`` lies under ``O``): replacing the folder ``O`` deletes the input;
* ``O`` *lies inside* ``I`` (a folder input), for a folder output: the output is written among
  the inputs it reads (and a folder of images would read it back on the next run). A single file
  output may lie inside an input folder (a ``calib.npz`` beside the captures it came from).

Each case is refused with one line naming both options. An input that does not exist (a
built-in name such as a texture, or a file the command will fail to read) has nothing to lose and
is skipped. A *holder* is a folder that holds inputs without being read as a whole (a run
directory: its ``config.yaml``, ``doe.npz`` and checkpoints are the inputs): an output may lie
inside it, but may not be it or contain it.

Folder outputs named after their inputs (``x.jpg`` -> ``x.png``) can collide: two inputs ``x.png``
and ``x.jpg`` would both become ``x.png``, the second silently replacing the first.
:func:`refuse_colliding_names` refuses such a set before any work, naming the inputs that clash
(the user renames one; edofproj never invents a name the user did not choose).

Across a whole command line, :func:`refuse_outputs_over_arguments` applies the rule's first case to
every output option (``--out``, ``--figure``, ``--preview``, ``--csv``, ...; the list is
:data:`edofproj.cli.OUTPUT_OPTIONS`) against every path any other option names: no output is an input,
and no two outputs are one file. ``edofproj`` applies it to every command before the command runs;
each command then applies :func:`refuse_output_over_inputs` with what it alone knows (the files a
lab manifest or a run directory lists, whether an output is a folder it replaces).

A training run's ``checkpoints/`` folder is written by training alone: :func:`refuse_output_in_checkpoints`
refuses any other output there (an export named ``last.pt`` would replace the run's newest checkpoint).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable, Sequence

from .errors import EdofprojError

#: An input or holder: ``(what the user called it, its path)``, e.g. ``("--images", "slides")``;
#: a path of None is skipped (an option not given).
NamedPath = tuple[str, "str | os.PathLike | None"]


def _resolved(path: str | os.PathLike) -> Path:
    """``path`` made absolute with symlinks and ``..`` resolved (the parts that exist)."""
    return Path(os.path.expanduser(os.fspath(path))).resolve()


def _same(a: Path, b: Path) -> bool:
    if a == b:
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _is_under(inner: Path, outer: Path) -> bool:
    """``inner`` lies strictly below ``outer``."""
    return inner != outer and inner.is_relative_to(outer)


def _named(option: str, path: str | os.PathLike) -> str:
    return f"{option} '{os.fspath(path)}'" if option else f"'{os.fspath(path)}'"


def refuse_output_over_inputs(
    output: str | os.PathLike | None,
    inputs: Iterable[NamedPath],
    option: str = "--out",
    holders: Iterable[NamedPath] = (),
    file_output: bool = False,
) -> None:
    """Raise one line when ``output`` is, contains or (unless ``file_output``: a single file) lies
    inside one of ``inputs``, or is or contains one of ``holders`` (module docstring); nothing when
    ``output`` is None."""
    if output is None:
        return
    out = _resolved(output)
    for what, path in inputs:
        if path is None or os.fspath(path) == "" or not os.path.lexists(os.fspath(path)):
            continue
        source = _resolved(path)
        if _same(out, source):
            raise _is_input_error(option, output, what, path)
        if _is_under(source, out):
            raise EdofprojError(
                f"{_named(option, output)} contains the input {_named(what, path)}: writing it would delete the "
                "input; write elsewhere"
            )
        if not file_output and _is_under(out, source):
            raise EdofprojError(
                f"{_named(option, output)} lies inside the input {_named(what, path)}: write outside the inputs"
            )
    for what, path in holders:
        if path is None or os.fspath(path) == "" or not os.path.isdir(os.fspath(path)):
            continue
        holder = _resolved(path)
        if _same(out, holder) or _is_under(holder, out):
            relation = "is" if _same(out, holder) else "contains"
            raise EdofprojError(
                f"{_named(option, output)} {relation} {_named(what, path)}, whose files are inputs: write "
                "elsewhere (a new folder, or one inside it)"
            )


def _is_input_error(option: str, output, what: str, path) -> EdofprojError:
    return EdofprojError(
        f"{_named(option, output)} is the input {_named(what, path)}: writing it would replace the input; write elsewhere"
    )


def refuse_outputs_over_arguments(outputs: Sequence[NamedPath], arguments: Iterable[NamedPath]) -> None:
    """Raise one line when an output of ``outputs`` (``(option, path)``) is the same file or folder
    as one of ``arguments`` (every other path the command line names; those not on disk are skipped)
    or as another output (module docstring)."""
    given = [(what, path) for what, path in arguments if path is not None and os.fspath(path) != ""]
    existing = [(what, path, _resolved(path)) for what, path in given if os.path.lexists(os.fspath(path))]
    named = [(option, path, _resolved(path)) for option, path in outputs if path is not None and os.fspath(path) != ""]
    for index, (option, output, out) in enumerate(named):
        for what, path, source in existing:
            if _same(out, source):
                raise _is_input_error(option, output, what, path)
        for other, other_path, resolved in named[:index]:
            if _same(out, resolved):
                raise EdofprojError(
                    f"{_named(option, output)} is also {_named(other, other_path)}: one would replace the other; "
                    "give each output its own path"
                )


#: A run's checkpoint folder and the file that makes a folder a run (``edofproj.runs``'
#: ``CHECKPOINT_DIR`` and ``CONFIG_NAME``; tests/test_output_options.py checks: not imported, the
#: foundation layer loads without torch).
CHECKPOINT_DIR, RUN_CONFIG_NAME = "checkpoints", "config.yaml"


def refuse_output_in_checkpoints(output: str | os.PathLike | None, option: str = "--out") -> None:
    """Raise one line when ``output`` is, or lies inside, the ``checkpoints/`` folder of a training run
    (a folder of that name beside a ``config.yaml``): training alone writes there (module docstring)."""
    if output is None or os.fspath(output) == "":
        return
    out = _resolved(output)
    for folder in (out, *out.parents):
        if folder.name == CHECKPOINT_DIR and (folder.parent / RUN_CONFIG_NAME).is_file():
            raise EdofprojError(
                f"{_named(option, output)} is inside the checkpoints of the run '{folder.parent}', which only "
                "training writes (the run reads its newest checkpoint from there): write elsewhere"
            )


def refuse_colliding_names(sources: Sequence[Path], output_name, what: str = "the inputs") -> None:
    """Raise one line when two of ``sources`` would be written under the same output name
    ``output_name(source)`` (module docstring: ``x.png`` and ``x.jpg`` both giving ``x.png``)."""
    seen: dict[str, Path] = {}
    clashes: list[tuple[Path, Path, str]] = []
    for source in sources:
        name = output_name(source)
        if name in seen:
            clashes.append((seen[name], source, name))
        else:
            seen[name] = source
    if clashes:
        first, second, name = clashes[0]
        more = f" (and {len(clashes) - 1} more clash(es))" if len(clashes) > 1 else ""
        raise EdofprojError(
            f"{what}: '{first.name}' and '{second.name}' would both be written as '{name}'{more}; "
            "rename one of them (one output per name)"
        )


__all__ = [
    "refuse_output_over_inputs",
    "refuse_outputs_over_arguments",
    "refuse_output_in_checkpoints",
    "refuse_colliding_names",
]
