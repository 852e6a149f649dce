"""A second device on a CPU-only machine: PyTorch's ``meta`` device, with the data kept on the CPU.

A tensor on the ``meta`` device has a shape, strides, a dtype and a storage, but no data; its
operators check devices the way CUDA's do (``Tensor on device cpu is not on the expected device
meta``). Alone it cannot run code that reads data back (``.item()``, ``if torch.any(...)``,
``.cpu().numpy()``, ``nonzero``). :class:`MetaDevice` is a ``TorchDispatchMode`` that gives every
meta storage a *shadow*: a CPU storage of the same bytes. Every operator on meta tensors runs twice,
on the meta tensors (devices and dtypes checked by PyTorch's own meta kernels) and on their shadows
(the values, by the CPU kernels), so a component runs exactly as on the CPU, reads included, while
its tensors claim another device. It fails where code would fail on a GPU:

* an operator mixes a meta tensor with a CPU tensor of one or more dimensions (a CPU scalar, 0-d,
  is allowed, as CUDA allows it; so are CPU index tensors of ``x[index]``, as CUDA allows them);
* a random draw onto the meta device takes a CPU ``torch.Generator`` (CUDA refuses it);
* with ``forbid_dtypes``: any meta tensor of those dtypes is made (e.g. float64 in a float32 network);
* ``.numpy()`` of a meta tensor, as of a CUDA one (PyTorch itself refuses it).

Reads back to the host (``.item()``, ``bool``, ``.cpu()``) are allowed and counted in
:attr:`MetaDevice.host_reads` (each is a synchronization on a GPU). :meth:`MetaDevice.data` gives a
meta tensor's values (a CPU copy), to compare with a plain CPU run.

What the meta device cannot do alone, and how it is done here:

* no meta kernel (data-dependent shapes: ``nonzero``, boolean masks): the output's shape is taken
  from the CPU result, and the op is listed in :attr:`MetaDevice.without_meta_kernel`; the device
  rule above still applies to its inputs;
* ``torch.tensor(data, device="meta")`` (also ``as_tensor``, ``asarray``, ``new_tensor``) of Python
  data drops the data: a ``TorchFunctionMode`` makes it on the CPU and moves it;
* ``torch.autocast`` refuses the meta device type even when disabled (and
  ``torch.is_autocast_enabled`` refuses to answer): inside :class:`MetaDevice` both take the CPU's;
  a disabled autocast does nothing on any device, and an enabled one (bf16) is *not* emulated;
* ``torch.save`` writes no data for meta tensors: inside :class:`MetaDevice` it writes their values
  on the CPU (a checkpoint of CUDA tensors, loaded with ``map_location="cpu"``, holds the same);
* CUDA's own API (``torch.cuda.*``, CUDA graphs, events, peak memory) has no meta counterpart.
"""

from __future__ import annotations

import collections
import traceback
from pathlib import Path

import torch
from torch.multiprocessing.reductions import StorageWeakRef
from torch.overrides import TorchFunctionMode
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten, tree_map, tree_unflatten

META = torch.device("meta")
CPU = torch.device("cpu")
aten = torch.ops.aten

#: ops that move data between devices (``to`` reaches the dispatch as such in inference mode)
TRANSFERS = {aten._to_copy, aten.to, aten.copy_, aten._copy_from, aten._copy_from_and_resize}
#: ops whose index tensors may stay on the CPU (CUDA accepts CPU indices there)
INDEXING = {aten.index.Tensor, aten.index_put.default, aten.index_put_.default, aten._index_put_impl_.default}
#: ops that return host values read from the data
HOST_READS = {aten._local_scalar_dense.default, aten.item.default, aten.equal.default, aten.is_nonzero.default}

SOURCE = str(Path(__file__).resolve().parents[1] / "src")


class DeviceMismatch(AssertionError):
    """A tensor made on the wrong device or in a forbidden dtype (the message names the op and the line)."""


def _library_line() -> str:
    """The innermost frame of the library (``src/``) in the current stack, as ``file:line``."""
    for frame in reversed(traceback.extract_stack()):
        if frame.filename.startswith(SOURCE):
            return f"{Path(frame.filename).relative_to(SOURCE)}:{frame.lineno} ({frame.line})"
    return "outside the library"


def _is_meta(x) -> bool:
    return isinstance(x, torch.Tensor) and x.device.type == "meta"


def _describe(t: torch.Tensor) -> str:
    return f"{t.device.type} {str(t.dtype).removeprefix('torch.')} {tuple(t.shape)}"


def _destination(func, args, kwargs) -> torch.device:
    """The device an op's output goes to: a ``device`` argument, the other tensor of ``to(other)`` or
    ``copy_(dst, src)``'s destination, else the first tensor argument's (CPU for a factory)."""
    packet = func.overloadpacket
    if packet in (aten.copy_, aten._copy_from, aten._copy_from_and_resize):
        return (args[0] if packet is aten.copy_ else args[1]).device
    for value in list(args[1:]) + list(kwargs.values()):
        if isinstance(value, (torch.device, str)) and (packet is not aten.to or isinstance(value, torch.device)):
            try:
                return torch.device(value)
            except RuntimeError:
                continue
    if packet is aten.to and len(args) > 1 and isinstance(args[1], torch.Tensor):
        return args[1].device
    first = next((x for x in args if isinstance(x, torch.Tensor)), None)
    return first.device if first is not None else CPU


class _AutocastOnMeta(torch.autocast):
    """``torch.autocast`` that takes ``device_type="meta"`` as the CPU's (see the module docstring)."""

    def __init__(self, device_type: str, *args, **kwargs) -> None:
        super().__init__("cpu" if device_type == "meta" else device_type, *args, **kwargs)


_IS_AUTOCAST_ENABLED = torch.is_autocast_enabled


def _is_autocast_enabled_on_meta(*device_type):
    """``torch.is_autocast_enabled`` that answers for the meta device type as for the CPU's."""
    return _IS_AUTOCAST_ENABLED(*("cpu" if d == "meta" else d for d in device_type))


class _DataOntoMeta(TorchFunctionMode):
    """``torch.tensor(data, device="meta")`` (and ``as_tensor``, ``asarray``, ``new_tensor`` of a meta
    tensor) of Python data: PyTorch drops the data of a meta tensor made from it; here it is made on
    the CPU and moved, so that :class:`MetaDevice` keeps it."""

    FROM_DATA = {torch.tensor, torch.as_tensor, torch.asarray}

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = dict(kwargs or {})
        if func is torch.Tensor.new_tensor and args[0].device.type == "meta" and "device" not in kwargs:
            source, data = args[0], args[1]
            kwargs.setdefault("dtype", source.dtype)
            kwargs["device"] = source.device
            func, args = torch.tensor, (data,)
        if func in self.FROM_DATA or func is torch.tensor:
            device = kwargs.get("device")
            if device is not None and torch.device(device).type == "meta" and not isinstance(args[0], torch.Tensor):
                requires_grad = kwargs.pop("requires_grad", False)
                made = func(*args, **dict(kwargs, device=CPU)).to(META)
                return made.requires_grad_() if requires_grad else made
        return func(*args, **kwargs)


class MetaDevice(TorchDispatchMode):
    """``with MetaDevice() as device:`` run code on ``meta`` tensors with CPU shadows (module docstring).

    ``forbid_dtypes``: dtypes no meta tensor may take inside (e.g. ``{torch.float64, torch.complex128}``
    for a float32 component).
    """

    def __init__(self, forbid_dtypes=()) -> None:
        super().__init__()
        self.forbid_dtypes = frozenset(forbid_dtypes)
        self._shadows: dict[int, tuple[StorageWeakRef, torch.UntypedStorage]] = {}
        self._ops = 0
        #: ``file:line`` of the library -> number of reads of device data back to the host
        self.host_reads: collections.Counter[str] = collections.Counter()
        #: ops that ran without a meta kernel (output shapes from the CPU run)
        self.without_meta_kernel: set[str] = set()

    # ------------------------------------------------------------------ public helpers
    def __enter__(self):
        self._autocast, self._is_autocast_enabled, self._save = torch.autocast, torch.is_autocast_enabled, torch.save
        torch.autocast = _AutocastOnMeta  # type: ignore[misc]
        torch.is_autocast_enabled = _is_autocast_enabled_on_meta  # type: ignore[assignment]
        torch.save = self._save_with_data  # type: ignore[assignment]
        self._from_data = _DataOntoMeta()
        self._from_data.__enter__()
        return super().__enter__()

    def __exit__(self, *exc):
        try:
            return super().__exit__(*exc)
        finally:
            self._from_data.__exit__(*exc)
            torch.autocast = self._autocast  # type: ignore[misc]
            torch.is_autocast_enabled = self._is_autocast_enabled  # type: ignore[assignment]
            torch.save = self._save  # type: ignore[assignment]

    def data(self, tensor: torch.Tensor) -> torch.Tensor:
        """The values of a meta tensor made inside the mode (a CPU copy, detached)."""
        return self._shadow(tensor.detach()).clone()

    def _save_with_data(self, obj, *args, **kwargs):
        """``torch.save`` with every meta tensor replaced by its values on the CPU: what a checkpoint
        of CUDA tensors holds once loaded with ``map_location="cpu"`` (PyTorch writes no data for meta)."""
        return self._save(tree_map(lambda x: self.data(x) if _is_meta(x) else x, obj), *args, **kwargs)

    # ------------------------------------------------------------------ shadows
    def _shadow(self, t: torch.Tensor) -> torch.Tensor:
        storage = t.untyped_storage()
        entry = self._shadows.get(storage._cdata)
        if entry is None or entry[0].expired():
            raise DeviceMismatch(
                f"a meta tensor {_describe(t)} made outside MetaDevice (no data) reached {_library_line()}"
            )
        view = torch.empty(0, dtype=t.dtype).set_(entry[1], t.storage_offset(), t.shape, t.stride())
        if t.is_conj():
            view = view.conj()
        if t.is_neg():
            view = view._neg_view()
        return view

    def _adopt(self, meta: torch.Tensor, value: torch.Tensor) -> None:
        """Give ``meta`` (an op's output) the values ``value`` unless its storage already has a shadow
        (a view or an in-place result: the CPU op wrote through the shadow already)."""
        storage = meta.untyped_storage()
        entry = self._shadows.get(storage._cdata)
        if entry is not None and not entry[0].expired():
            return
        self._shadows[storage._cdata] = (StorageWeakRef(storage), torch.UntypedStorage(storage.nbytes()))
        if meta.numel():
            self._shadow(meta).copy_(value)
        self._ops += 1
        if self._ops % 2000 == 0:  # drop the shadows of freed meta storages
            self._shadows = {k: v for k, v in self._shadows.items() if not v[0].expired()}

    # ------------------------------------------------------------------ the dispatch
    def _check_devices(self, func, args, kwargs) -> None:
        flat, _ = tree_flatten((args, kwargs))
        tensors = [x for x in flat if isinstance(x, torch.Tensor)]
        if func.overloadpacket in TRANSFERS:
            return
        if func in INDEXING:  # x[index]: the index tensors may be on the CPU
            indices = args[1] if len(args) > 1 else kwargs.get("indices", ())
            skip = {id(i) for i in indices if isinstance(i, torch.Tensor)}
            tensors = [t for t in tensors if id(t) not in skip]
        for t in tensors:
            if t.device.type != "meta" and t.dim() > 0:
                raise DeviceMismatch(
                    f"{func} mixes devices ({', '.join(_describe(x) for x in tensors)}) at {_library_line()}"
                )
        generator = kwargs.get("generator")
        if generator is not None and generator.device.type != "meta":
            raise DeviceMismatch(
                f"{func} draws onto the meta device with a {generator.device} generator at {_library_line()}"
            )

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        flat, _ = tree_flatten((args, kwargs))
        on_meta = any(isinstance(x, torch.Tensor) and x.device.type == "meta" for x in flat)
        to_meta = _destination(func, args, kwargs).type == "meta"
        if not (on_meta or to_meta):
            return func(*args, **kwargs)
        self._check_devices(func, args, kwargs)

        def shadow(x):
            if isinstance(x, torch.Tensor) and x.device.type == "meta":
                return self._shadow(x)
            if isinstance(x, torch.device) and x.type == "meta":
                return CPU
            return x

        s_args, s_kwargs = tree_map(shadow, (args, kwargs))
        if "generator" in s_kwargs:
            s_kwargs = dict(s_kwargs, generator=kwargs["generator"])
        out_of_meta = func.overloadpacket in TRANSFERS and _destination(func, args, kwargs).type != "meta"
        if func in HOST_READS or out_of_meta:
            self.host_reads[_library_line()] += 1
            return func(*s_args, **s_kwargs)

        try:
            out = func(*args, **kwargs)
            fallback = False
        except NotImplementedError as exc:  # no meta kernel (data-dependent output shape)
            if "copy out of meta" in str(exc):
                raise
            fallback = True
            self.without_meta_kernel.add(str(func))
        s_out = func(*s_args, **s_kwargs)
        if fallback:
            if func._schema.is_mutable:
                out = args[0]
            else:
                out = tree_map(
                    lambda s: (
                        torch.empty_strided(s.shape, s.stride(), dtype=s.dtype, device=META)
                        if isinstance(s, torch.Tensor)
                        else s
                    ),
                    s_out,
                )
        metas, spec = tree_flatten(out)
        values, _ = tree_flatten(s_out)
        for m, v in zip(metas, values):
            if isinstance(m, torch.Tensor) and m.device.type == "meta":
                if m.dtype in self.forbid_dtypes:
                    raise DeviceMismatch(f"{func} made a {_describe(m)} tensor (forbidden here) at {_library_line()}")
                self._adopt(m, v)
        return tree_unflatten(metas, spec)
