"""Read a TorchScript archive (a zip: `data.pkl`, `data/N` storages, `code/`) without torch.

`data.pkl` is a pickle of the module tree. We unpickle it with a restricted Unpickler:
`__torch__.*` module classes become plain `TSObj` containers (their state dict becomes
attributes, in pickled order), tensor-rebuild records become numpy arrays read from the
raw little-endian storage files, and every other global is refused. No code from the
archive is executed.
"""

import collections
import pickle
import re
import zipfile

import numpy as np


class TSObj:
    """A TorchScript module instance: `ts_type` is its qualified class name."""

    ts_type = "?"

    def __setstate__(self, state):
        self.__dict__.update(state)

    def children(self):
        """(name, child) pairs of sub-modules, in pickled (= declaration) order."""
        return [(k, v) for k, v in self.__dict__.items() if isinstance(v, TSObj)]

    def __repr__(self):
        return f"<{self.ts_type}>"


_STORAGE_DTYPES = {"FloatStorage": "<f4", "DoubleStorage": "<f8", "LongStorage": "<i8", "IntStorage": "<i4"}


def _rebuild_tensor_v2(storage, offset, size, stride, requires_grad=False, hooks=None, metadata=None):
    itemsize = storage.dtype.itemsize
    if len(size) == 0:
        return storage[offset].copy()
    arr = np.lib.stride_tricks.as_strided(storage[offset:], shape=tuple(size), strides=tuple(s * itemsize for s in stride))
    return np.ascontiguousarray(arr)


class _Unpickler(pickle.Unpickler):
    def __init__(self, f, zf, prefix):
        super().__init__(f)
        self.zf = zf
        self.prefix = prefix
        self.classes = {}

    def find_class(self, module, name):
        if module.startswith("__torch__."):
            key = f"{module}.{name}"
            if key not in self.classes:
                self.classes[key] = type(name, (TSObj,), {"ts_type": key})
            return self.classes[key]
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor_v2
        if module == "torch" and name in _STORAGE_DTYPES:
            return _STORAGE_DTYPES[name]
        if (module, name) == ("collections", "OrderedDict"):
            return collections.OrderedDict
        if (module, name) == ("torch.jit._pickle", "build_intlist"):
            return list
        raise pickle.UnpicklingError(f"refusing global {module}.{name}")

    def persistent_load(self, pid):
        kind, dtype, key, _location, numel = pid
        if kind != "storage" or dtype not in _STORAGE_DTYPES.values():
            raise pickle.UnpicklingError(f"unsupported persistent id {pid!r}")
        raw = self.zf.read(f"{self.prefix}data/{key}")
        arr = np.frombuffer(raw, dtype=dtype, count=numel)
        return arr


class Archive:
    """A TorchScript archive opened from a path or a file object."""

    def __init__(self, src):
        self.zf = zipfile.ZipFile(src)
        names = self.zf.namelist()
        pkl = [n for n in names if n.endswith("/data.pkl") and n.count("/") == 1]
        if len(pkl) != 1:
            raise ValueError(f"not a TorchScript archive (data.pkl entries: {pkl})")
        self.prefix = pkl[0][: -len("data.pkl")]
        with self.zf.open(pkl[0]) as f:
            self.root = _Unpickler(f, self.zf, self.prefix).load()

    def code(self, relpath):
        """Text of `code/__torch__/<relpath>` in the archive."""
        return self.zf.read(f"{self.prefix}code/__torch__/{relpath}").decode()

    def pool_params(self, ts_type):
        """Parse a pooling class's forward() call in the archive's code: returns
        (op, kernel, stride, pad, count_include_pad) with op 'max' or 'avg'."""
        # "__torch__.torch.nn.modules.pooling.___torch_mangle_6.MaxPool2d" -> file + class
        parts = ts_type.split(".")
        relpath = "/".join(parts[1:-1]) + ".py"
        text = self.code(relpath)
        cls = parts[-1]
        body = text[text.index(f"class {cls}(") :]
        nxt = body.find("\nclass ", 1)
        body = body if nxt < 0 else body[:nxt]
        is_max = "_max_pool2d" in body
        m = is_max and re.search(r"\w+\(input, \[(\d+), (\d+)\], \[(\d+), (\d+)\], \[(\d+), (\d+)\], \[1, 1\], False", body)
        if m:
            k, s, p = (int(m.group(1)), int(m.group(2))), (int(m.group(3)), int(m.group(4))), (int(m.group(5)), int(m.group(6)))
            return "max", k, s, p, None
        m = re.search(r"torch\.avg_pool2d\(input, \[(\d+), (\d+)\], \[(\d+), (\d+)\], \[(\d+), (\d+)\](.*)\)", body)
        if m:
            k, s, p = (int(m.group(1)), int(m.group(2))), (int(m.group(3)), int(m.group(4))), (int(m.group(5)), int(m.group(6)))
            rest = [t.strip() for t in m.group(7).split(",") if t.strip()]
            # avg_pool2d(input, kernel, stride, padding, ceil_mode=False, count_include_pad=True)
            if rest and rest[0] != "False":
                raise ValueError(f"{ts_type}: ceil_mode not supported")
            cip = True if len(rest) < 2 else rest[1] == "True"
            return "avg", k, s, p, cip
        raise ValueError(f"cannot parse pooling code of {ts_type}")
