"""Restricted reader for torch's legacy (pre-zip, torch < 1.6) ``.pth`` pickle format, numpy only.

The legacy format is a concatenation of pickles followed by raw storage bytes:

1. the magic number ``0x1950A86A20F9469CFC6C``,
2. the protocol version (1001),
3. a ``sys_info`` dict (endianness, C type sizes),
4. the object itself (here a state-dict ``OrderedDict``); tensors appear as
   ``torch._utils._rebuild_tensor_v2(storage, offset, size, stride, ...)`` whose ``storage`` is a
   persistent id ``("storage", StorageType, key, location, numel, view_metadata)``,
5. the list of storage keys, in the order their data follows,
6. per storage: an int64 element count then the little-endian elements.

Only the handful of globals a state dict needs are resolvable; anything else (``os.system``,
arbitrary classes) raises, so a malicious file cannot execute code. Torch is never imported.
"""

from __future__ import annotations

import collections
import io
import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_MAGIC_NUMBER = 0x1950A86A20F9469CFC6C
_PROTOCOL_VERSION = 1001

_STORAGE_DTYPES: dict[str, np.dtype] = {
    "FloatStorage": np.dtype("<f4"),
    "DoubleStorage": np.dtype("<f8"),
    "HalfStorage": np.dtype("<f2"),
    "LongStorage": np.dtype("<i8"),
    "IntStorage": np.dtype("<i4"),
    "ShortStorage": np.dtype("<i2"),
    "CharStorage": np.dtype("i1"),
    "ByteStorage": np.dtype("u1"),
    "BoolStorage": np.dtype("?"),
}


class TorchPickleError(ValueError):
    """A ``.pth`` file is not a readable legacy torch state dict."""


@dataclass(frozen=True)
class _StorageType:
    name: str

    @property
    def dtype(self) -> np.dtype:
        return _STORAGE_DTYPES[self.name]


@dataclass(frozen=True)
class _LazyTensor:
    """A tensor whose storage bytes come after the main pickle; materialised later."""

    storage_key: str
    offset: int
    size: tuple[int, ...]
    stride: tuple[int, ...]


def _rebuild_tensor_v2(storage, storage_offset, size, stride, requires_grad=False, hooks=None, *_):
    del requires_grad, hooks
    return _LazyTensor(storage, int(storage_offset), tuple(size), tuple(stride))


def _rebuild_tensor(storage, storage_offset, size, stride):
    return _LazyTensor(storage, int(storage_offset), tuple(size), tuple(stride))


def _rebuild_parameter(data, requires_grad=False, hooks=None, *_):
    del requires_grad, hooks
    return data


class _RestrictedUnpickler(pickle.Unpickler):
    """Resolves only the globals a torch state dict needs; records storage declarations."""

    def __init__(self, file, path: Path):
        super().__init__(file)
        self._path = path
        self.storages: dict[str, tuple[np.dtype, int]] = {}

    def find_class(self, module: str, name: str):
        if module == "collections" and name == "OrderedDict":
            return collections.OrderedDict
        if module == "torch._utils":
            table = {
                "_rebuild_tensor_v2": _rebuild_tensor_v2,
                "_rebuild_tensor": _rebuild_tensor,
                "_rebuild_parameter": _rebuild_parameter,
            }
            if name in table:
                return table[name]
        if module == "torch" and name in _STORAGE_DTYPES:
            return _StorageType(name)
        raise TorchPickleError(
            f"{self._path}: refusing to load global {module}.{name} (only torch state dicts "
            "of plain tensors are supported)"
        )

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) >= 5 and pid[0] == "storage"):
            raise TorchPickleError(f"{self._path}: unsupported persistent id {pid!r}")
        storage_type, key, _location, numel = pid[1], str(pid[2]), pid[3], int(pid[4])
        if not isinstance(storage_type, _StorageType):
            raise TorchPickleError(f"{self._path}: bad storage type {storage_type!r}")
        if len(pid) > 5 and pid[5] is not None:
            raise TorchPickleError(f"{self._path}: storage views are not supported")
        self.storages[key] = (storage_type.dtype, numel)
        return key


class _NoGlobalsUnpickler(pickle.Unpickler):
    """For the header pickles and the key list: plain Python values only."""

    def find_class(self, module: str, name: str):
        raise TorchPickleError(f"unexpected global {module}.{name} in a .pth header")


def load_legacy_torch_state_dict(path: str | Path) -> dict[str, np.ndarray]:
    """Reads a legacy-format torch ``.pth`` state dict into numpy arrays, without torch.

    Args:
      path: the ``.pth`` file (torch's pre-1.6 serialisation: sequential pickles + raw storages).

    Returns:
      An ordered ``{name: array}`` dict; arrays keep the torch layout (e.g. conv weights as
      ``out × in × kh × kw``) and dtype (float32, int64 ...).

    Raises:
      FileNotFoundError: the file does not exist.
      TorchPickleError: the file is not a legacy torch pickle, is truncated, or references
        anything other than plain tensors (e.g. code objects).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"torch weights file not found: {path}")
    raw = path.read_bytes()
    f = io.BytesIO(raw)
    try:
        magic = _NoGlobalsUnpickler(f).load()
        if magic != _MAGIC_NUMBER:
            raise TorchPickleError(
                f"{path}: not a legacy torch .pth (bad magic number {magic!r}; zip-format "
                "checkpoints from torch >= 1.6 are not supported)"
            )
        version = _NoGlobalsUnpickler(f).load()
        if version != _PROTOCOL_VERSION:
            raise TorchPickleError(f"{path}: unsupported torch protocol version {version!r}")
        sys_info = _NoGlobalsUnpickler(f).load()
        if not isinstance(sys_info, dict) or not sys_info.get("little_endian", False):
            raise TorchPickleError(f"{path}: only little-endian files are supported")
        unpickler = _RestrictedUnpickler(f, path)
        obj = unpickler.load()
        keys = _NoGlobalsUnpickler(f).load()
    except TorchPickleError:
        raise
    except Exception as e:  # noqa: BLE001 - any pickle failure means a corrupt file
        raise TorchPickleError(f"{path}: corrupt or truncated torch pickle ({e!r})") from e

    if not isinstance(obj, dict):
        raise TorchPickleError(f"{path}: top-level object is {type(obj).__name__}, expected a dict")
    if not isinstance(keys, list) or set(map(str, keys)) != set(unpickler.storages):
        raise TorchPickleError(f"{path}: storage key list does not match the declared storages")

    storages: dict[str, np.ndarray] = {}
    pos = f.tell()
    for key in map(str, keys):
        dtype, numel = unpickler.storages[key]
        if pos + 8 > len(raw):
            raise TorchPickleError(f"{path}: truncated before storage {key}")
        count = int(np.frombuffer(raw, "<i8", 1, pos)[0])
        if count != numel:
            raise TorchPickleError(
                f"{path}: storage {key} declares {numel} elements but the data has {count}"
            )
        pos += 8
        nbytes = count * dtype.itemsize
        if pos + nbytes > len(raw):
            raise TorchPickleError(f"{path}: truncated inside storage {key}")
        storages[key] = np.frombuffer(raw, dtype, count, pos)
        pos += nbytes

    out: dict[str, np.ndarray] = {}
    for name, value in obj.items():
        if not isinstance(value, _LazyTensor):
            raise TorchPickleError(
                f"{path}: entry {name!r} is {type(value).__name__}, not a tensor"
            )
        flat = storages[value.storage_key]
        itemsize = flat.dtype.itemsize
        span = (
            1 + sum((n - 1) * s for n, s in zip(value.size, value.stride, strict=True))
            if all(value.size)
            else 0
        )
        if value.offset + span > flat.size:
            raise TorchPickleError(f"{path}: entry {name!r} reads past its storage")
        arr = np.lib.stride_tricks.as_strided(
            flat[value.offset :],
            shape=value.size,
            strides=tuple(s * itemsize for s in value.stride),
        )
        out[str(name)] = np.array(arr)  # own, contiguous copy
    return out
