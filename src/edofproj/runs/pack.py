"""A run directory as a few files of bounded size, and back into a run directory.

A leased machine (a GPU lent for minutes) returns only a few files of limited size, and takes only
a limited working tree along. :func:`pack_run` writes a run as

    NAME.tar.000, NAME.tar.001, ...   one uncompressed tar of the run's files, cut into parts of at
                                      most ``part_bytes`` bytes each (at most ``max_parts`` parts)
    NAME.pack.json                    the manifest: format, step, whether the run can be resumed, each
                                      file's and each part's size and SHA-256

and :func:`unpack_run` checks every part against the manifest, joins them, checks every file and
writes a new run directory (atomically: a staging folder renamed into place).

What is packed (:func:`pack_members`): ``config.yaml``, ``doe.npz``, ``train_log.csv``,
``validation_log.csv`` and ``figures/*.png`` where present, and ``checkpoints/last.pt``:

* ``resumable=True``: the checkpoint as it is (network, DOE, Adam's moments, the schedule and the
  random states: :mod:`.checkpoint`), so that ``edofproj train --resume`` on the unpacked run continues
  bit for bit as the run would have gone on where it was packed;
* ``resumable=False``: the checkpoint slimmed to the network and the DOE, as a built-in run ships
  (:func:`edofproj.builtin_runs.slim_checkpoint`): about a third of the bytes (Adam keeps two moments per
  parameter), enough to evaluate, export or fine-tune the run, not to resume it.

The tar's size is known before anything is written (:func:`tar_bytes`: a 512-byte header per member,
each file padded to 512 bytes, two zero blocks, padded to tar's 10,240-byte record), so a run that does
not fit is refused with nothing written. The floating-point state compresses poorly (gzip saves about
9 % on a trained network), so the parts are not compressed.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shutil
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterator

from ..builtin_runs import slim_checkpoint
from ..errors import EdofprojError
from ..fileio import atomic_path, user_mode, write_text_atomic
from ..outputs import refuse_output_over_inputs
from .checkpoint import LAST_NAME, load_checkpoint
from .directory import CHECKPOINT_DIR, CONFIG_NAME, DOE_NAME, FIGURES_DIR, check_new_run_dir, run_inputs

FORMAT = "edofproj-run-pack-v1"
MANIFEST_SUFFIX = ".pack.json"
#: The run's files a pack holds besides its checkpoint (each where present).
OPTIONAL_FILES = (DOE_NAME, "train_log.csv", "validation_log.csv")
CHECKPOINT_MEMBER = f"{CHECKPOINT_DIR}/{LAST_NAME}"
TAR_BLOCK = 512
TAR_RECORD = 20 * TAR_BLOCK
_CHUNK = 1 << 20


@dataclass(frozen=True)
class PackedRun:
    """A written pack: its manifest, its parts (in order), the run's step, whether it resumes, the tar's bytes."""

    manifest: Path
    parts: tuple[Path, ...]
    step: int
    resumable: bool
    tar_bytes: int


def manifest_path(out_dir: str | Path, name: str) -> Path:
    return Path(out_dir) / f"{name}{MANIFEST_SUFFIX}"


def part_name(name: str, index: int) -> str:
    return f"{name}.tar.{index:03d}"


def pack_members(run_dir: str | Path) -> dict[str, Path]:
    """``{name in the tar: file}``: what a pack of ``run_dir`` holds (module docstring), the checkpoint
    last; a one-line error when the run has no ``config.yaml`` or no ``checkpoints/last.pt``."""
    run = Path(run_dir)
    for required in (CONFIG_NAME, CHECKPOINT_MEMBER):
        if not (run / required).is_file():
            raise EdofprojError(f"'{run}' has no {required}: not a trained run (nothing to pack)")
    members = {CONFIG_NAME: run / CONFIG_NAME}
    members.update({name: run / name for name in OPTIONAL_FILES if (run / name).is_file()})
    figures = run / FIGURES_DIR
    if figures.is_dir():
        members.update({f"{FIGURES_DIR}/{p.name}": p for p in sorted(figures.glob("*.png")) if p.is_file()})
    members[CHECKPOINT_MEMBER] = run / CHECKPOINT_MEMBER
    return members


def tar_bytes(sizes: list[int]) -> int:
    """The bytes of an uncompressed tar of files of ``sizes`` bytes with names under 100 characters:
    ``sum(512 + ceil(size / 512) 512) + 2 512``, rounded up to a multiple of 10,240."""
    body = sum(TAR_BLOCK + math.ceil(size / TAR_BLOCK) * TAR_BLOCK for size in sizes) + 2 * TAR_BLOCK
    return math.ceil(body / TAR_RECORD) * TAR_RECORD


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for chunk in iter(lambda: handle.read(_CHUNK), b""):
            digest.update(chunk)
    return digest.hexdigest()


class _PartWriter:
    """A write-only stream that fills ``NAME.tar.000``, ``.001``, ... of ``part_bytes`` each in ``out_dir``,
    each written atomically; the SHA-256 and bytes of each finished part in :attr:`parts`."""

    def __init__(self, out_dir: Path, name: str, part_bytes: int, stack: contextlib.ExitStack):
        self.out_dir, self.name, self.part_bytes, self.stack = out_dir, name, part_bytes, stack
        self.parts: list[dict] = []
        self.handle: BinaryIO | None = None
        self.digest = hashlib.sha256()
        self.written = 0

    def _open(self) -> None:
        index = len(self.parts)
        tmp = self.stack.enter_context(atomic_path(self.out_dir / part_name(self.name, index)))
        self.handle = self.stack.enter_context(tmp.open("wb"))
        self.digest = hashlib.sha256()
        self.written = 0

    def _close_part(self) -> None:
        if self.handle is not None:
            self.handle.close()
            self.parts.append(
                {
                    "file": part_name(self.name, len(self.parts)),
                    "bytes": self.written,
                    "sha256": self.digest.hexdigest(),
                }
            )
            self.handle = None

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view.nbytes:
            if self.handle is None:
                self._open()
            assert self.handle is not None
            room = self.part_bytes - self.written
            chunk = view[:room]
            self.handle.write(chunk)
            self.digest.update(chunk)
            self.written += chunk.nbytes
            view = view[chunk.nbytes :]
            if self.written == self.part_bytes:
                self._close_part()
        return len(data)

    def close(self) -> None:
        self._close_part()


def pack_run(
    run_dir: str | Path,
    out_dir: str | Path,
    name: str = "run",
    part_bytes: int = 16_000_000,
    max_parts: int = 4,
    resumable: bool = True,
) -> PackedRun:
    """Write the pack ``NAME.tar.NNN`` + ``NAME.pack.json`` of ``run_dir`` into ``out_dir`` (module
    docstring); parts of an earlier pack of that name beyond the new ones are removed. Refused with one
    line, before anything is written, when the tar would need more than ``max_parts`` parts."""
    run, out = Path(run_dir), Path(out_dir)
    if part_bytes < TAR_RECORD or max_parts < 1:
        raise EdofprojError(f"a pack needs parts of at least {TAR_RECORD} bytes and at least one part")
    if not name or any(c not in "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._-" for c in name):
        raise EdofprojError(f"pack name '{name}': use letters, digits, '.', '_' and '-' only")
    refuse_output_over_inputs(out, run_inputs(run, "the run"), "the pack's folder")
    members = pack_members(run)
    with tempfile.TemporaryDirectory(prefix="edofproj-pack-") as scratch:
        if not resumable:
            members[CHECKPOINT_MEMBER] = slim_checkpoint(members[CHECKPOINT_MEMBER], Path(scratch) / LAST_NAME)
        step = int(load_checkpoint(members[CHECKPOINT_MEMBER])["step"])
        sizes = {arcname: path.stat().st_size for arcname, path in members.items()}
        total = tar_bytes(list(sizes.values()))
        needed = math.ceil(total / part_bytes)
        if needed > max_parts:
            kind = "resumable (with the optimizer's state)" if resumable else "slimmed to the network and DOE"
            raise EdofprojError(
                f"the run '{run}' packed {kind} is {total / 1e6:.1f} MB, {needed} parts of {part_bytes / 1e6:g} MB: "
                f"more than the {max_parts} allowed"
            )
        files = {arcname: {"bytes": sizes[arcname], "sha256": _sha256(path)} for arcname, path in members.items()}
        out.mkdir(parents=True, exist_ok=True)
        with contextlib.ExitStack() as stack:
            writer = _PartWriter(out, name, part_bytes, stack)
            with tarfile.open(fileobj=writer, mode="w|", format=tarfile.USTAR_FORMAT) as tar:  # type: ignore[call-overload]
                for arcname, path in members.items():
                    info = tar.gettarinfo(str(path), arcname=arcname)
                    info.uid = info.gid = 0
                    info.uname = info.gname = ""
                    with path.open("rb") as handle:
                        tar.addfile(info, handle)
            writer.close()
            parts = writer.parts
        if sum(p["bytes"] for p in parts) != total:
            raise EdofprojError(f"internal error: the pack of '{run}' is not the {total} bytes predicted")
    manifest = {
        "format": FORMAT,
        "name": name,
        "step": step,
        "resumable": resumable,
        "tar_bytes": total,
        "files": files,
        "parts": parts,
    }
    target = manifest_path(out, name)
    write_text_atomic(target, json.dumps(manifest, indent=1) + "\n")
    for index in range(len(parts), 1000):
        stale = out / part_name(name, index)
        if not stale.exists():
            break
        stale.unlink()
    return PackedRun(target, tuple(out / p["file"] for p in parts), step, resumable, total)


def read_manifest(path: str | Path) -> dict:
    """The manifest of a pack, checked for its format and keys (one-line errors)."""
    path = Path(path)
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise EdofprojError(f"no pack manifest at '{path}'") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise EdofprojError(f"cannot read the pack manifest '{path}': {type(exc).__name__}") from None
    keys = ("name", "step", "resumable", "tar_bytes", "files", "parts")
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT or any(k not in manifest for k in keys):
        raise EdofprojError(f"'{path}' is not an edofproj run pack manifest ({FORMAT})")
    return manifest


def _checked_parts(manifest: dict, folder: Path, where: Path) -> list[Path]:
    parts = []
    for part in manifest["parts"]:
        path = folder / Path(str(part["file"])).name
        if not path.is_file():
            raise EdofprojError(f"the pack '{where}' misses its part '{path.name}'")
        if path.stat().st_size != int(part["bytes"]) or _sha256(path) != part["sha256"]:
            raise EdofprojError(
                f"the part '{path}' of the pack '{where}' is damaged or from another pack (its size or SHA-256 "
                "differs from the manifest's)"
            )
        parts.append(path)
    return parts


class _JoinedParts:
    """A read-only stream of the parts one after the other."""

    def __init__(self, parts: list[Path]):
        self.parts: Iterator[Path] = iter(parts)
        self.handle: BinaryIO | None = None

    def read(self, size: int = -1) -> bytes:
        chunks = []
        while size != 0:
            if self.handle is None:
                path = next(self.parts, None)
                if path is None:
                    break
                self.handle = path.open("rb")
            data = self.handle.read(size if size > 0 else -1)
            if not data:
                self.handle.close()
                self.handle = None
                continue
            chunks.append(data)
            if size > 0:
                size -= len(data)
        return b"".join(chunks)

    def close(self) -> None:
        if self.handle is not None:
            self.handle.close()


def unpack_run(manifest: str | Path, run_dir: str | Path) -> Path:
    """Write the run of the pack whose manifest is ``manifest`` (its parts beside it) as the new run
    directory ``run_dir`` (absent or empty). Every part's and every file's size and SHA-256 are checked
    against the manifest, and only the manifest's regular files are written; a one-line error otherwise,
    with ``run_dir`` left as it was. Returns ``run_dir``."""
    where = Path(manifest)
    content = read_manifest(where)
    run = Path(run_dir)
    check_new_run_dir(run, hint="unpack into a new folder")
    parts = _checked_parts(content, where.parent, where)
    expected: dict[str, dict] = content["files"]
    run.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{run.name}.unpacking-", dir=run.parent))
    os.chmod(staging, user_mode(0o777))  # mkdtemp makes 0700; a run directory gets the usual permissions
    try:
        stream = _JoinedParts(parts)
        seen = set()
        with tarfile.open(fileobj=stream, mode="r|") as tar:  # type: ignore[call-overload]
            for member in tar:
                name = member.name
                if name not in expected or not member.isfile() or name in seen:
                    raise EdofprojError(f"the pack '{where}' holds '{name}', which its manifest does not list")
                seen.add(name)
                target = staging / name
                target.parent.mkdir(parents=True, exist_ok=True)
                source = tar.extractfile(member)
                assert source is not None
                with target.open("wb") as handle:
                    shutil.copyfileobj(source, handle, _CHUNK)
                if target.stat().st_size != int(expected[name]["bytes"]) or _sha256(target) != expected[name]["sha256"]:
                    raise EdofprojError(f"the file '{name}' of the pack '{where}' differs from its manifest's")
        stream.close()
        missing = sorted(set(expected) - seen)
        if missing:
            raise EdofprojError(f"the pack '{where}' lacks {', '.join(missing)}, which its manifest lists")
        try:
            if run.is_dir():
                run.rmdir()  # empty: check_new_run_dir
            os.replace(staging, run)
        except OSError as exc:
            raise EdofprojError(f"cannot write the run '{run}': {exc.strerror or exc}") from None
    except tarfile.TarError as exc:
        shutil.rmtree(staging, ignore_errors=True)
        raise EdofprojError(f"the pack '{where}' is not a readable tar ({exc})") from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return run
