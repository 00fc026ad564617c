"""Host functions (MuJoCo C: the native step, site kinematics, the oracles) as JAX operations
that JAX's persistent compilation cache keeps (:func:`host_call`; docs/performance.md).

JAX writes no program with a ``jax.pure_callback`` to its cache. These programs call one XLA
FFI target (:data:`TARGET`, a ctypes handler registered through ``jax.ffi``; XLA's
ABI-stable C API, ``xla/ffi/api/c_api.h``, version 0.1) with a key that names what the
function computes from, the same in every process.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Callable

import numpy as np

_METADATA = 1  # XLA_FFI_Extension_Metadata
_EXECUTE = 3  # XLA_FFI_ExecutionStage_EXECUTE
_F32 = 11  # XLA_FFI_DataType_F32
_INTERNAL = 13  # XLA_FFI_Error_Code_INTERNAL


_P, _I64 = ctypes.c_void_p, ctypes.c_int64
_HEAD = [("struct_size", ctypes.c_size_t), ("extension", _P)]  # every XLA FFI structure's


def _struct(name: str, fields: list) -> type:
    return type(name, (ctypes.Structure,), {"_fields_": fields})


_Extension = _struct("_Extension", [("struct_size", ctypes.c_size_t), ("type", ctypes.c_int),
                                    ("next", _P)])  # fmt: skip
_Version = _struct("_Version", _HEAD + [("major", ctypes.c_int), ("minor", ctypes.c_int)])
_Metadata = _struct("_Metadata", [("struct_size", ctypes.c_size_t), ("api_version", _Version),
                                  ("traits", ctypes.c_uint32), ("state_type", _I64)])  # fmt: skip
_MetadataPtr = ctypes.POINTER(_Metadata)
_MetadataExtension = _struct(
    "_MetadataExtension", [("base", _Extension), ("metadata", _MetadataPtr)]
)
_Buffer = _struct("_Buffer", _HEAD + [("dtype", ctypes.c_int), ("data", _P), ("rank", _I64),
                                      ("dims", _P)])  # fmt: skip
_ByteSpan = _struct("_ByteSpan", [("ptr", _P), ("len", ctypes.c_size_t)])
_List = _struct("_List", _HEAD + [("size", _I64), ("types", _P), ("items", _P)])  # args, rets
_Attrs = _struct("_Attrs", _HEAD + [("size", _I64), ("types", _P), ("names", _P), ("items", _P)])
_CallFrame = _struct("_CallFrame", _HEAD + [
    ("api", _P), ("ctx", _P), ("stage", ctypes.c_int), ("args", _List), ("rets", _List),
    ("attrs", _Attrs), ("future", _P)])  # fmt: skip
_ErrorArgs = _struct("_ErrorArgs", _HEAD + [("message", ctypes.c_char_p), ("errc", ctypes.c_int)])

_ERROR_CREATE = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.POINTER(_ErrorArgs))
_ERROR_CREATE_AT = 2 * 8 + ctypes.sizeof(_Version) + 8  # XLA_FFI_Api.XLA_FFI_Error_Create
_pointer = ctypes.c_void_p.from_address


_DIMS = [ctypes.c_int64 * rank for rank in range(9)]
_VIEWS: dict[tuple, np.ndarray] = {}  # (address, shape) -> a view of it: XLA reuses addresses


def _array(address: int) -> np.ndarray:
    # The float32 XLA_FFI_Buffer at ``address`` as a NumPy view (no copy).
    buffer = _Buffer.from_address(address)
    if buffer.dtype != _F32:
        raise TypeError(f"an FFI buffer of XLA type {buffer.dtype}, not float32")
    shape = tuple(_DIMS[buffer.rank].from_address(buffer.dims))
    view = _VIEWS.get((buffer.data, shape))
    if view is None:
        if len(_VIEWS) > 4096:
            _VIEWS.clear()
        size = math.prod(shape)
        memory = (ctypes.c_float * size).from_address(buffer.data)
        view = _VIEWS[buffer.data, shape] = np.frombuffer(memory, np.float32).reshape(shape)
    return view


def _key(attrs: _Attrs) -> str:
    for k in range(attrs.size):
        name = _ByteSpan.from_address(_pointer(attrs.names + 8 * k).value)
        if ctypes.string_at(name.ptr, name.len) == b"key":
            value = _ByteSpan.from_address(_pointer(attrs.items + 8 * k).value)
            return ctypes.string_at(value.ptr, value.len).decode()
    raise KeyError("the FFI call has no attribute 'key'")


def _error(frame: _CallFrame, error: BaseException) -> int:
    # An XLA_FFI_Error for ``error``: XLA raises it in the caller, message included.
    message = f"{type(error).__name__}: {error}".encode()
    args = _ErrorArgs(ctypes.sizeof(_ErrorArgs), None, message, _INTERNAL)
    create = _ERROR_CREATE(_pointer(frame.api + _ERROR_CREATE_AT).value)
    return create(ctypes.byref(args))


def _handler(fn: Callable[[str, list, list], None]):
    # A C function of XLA's FFI handler type (ctypes; the caller keeps it) that calls
    # fn(key, inputs, outputs) with float32 NumPy views; an exception becomes XLA's error.

    def call(address):
        frame = _CallFrame.from_address(address)
        try:
            if frame.extension and _Extension.from_address(frame.extension).type == _METADATA:
                meta = _MetadataExtension.from_address(frame.extension).metadata.contents
                meta.api_version = _Version(ctypes.sizeof(_Version), None, 0, 1)
                meta.traits, meta.state_type = 0, 0
                return None
            if frame.stage != _EXECUTE:
                return None
            inputs = [
                _array(_pointer(frame.args.items + 8 * k).value) for k in range(frame.args.size)
            ]
            outputs = [
                _array(_pointer(frame.rets.items + 8 * k).value) for k in range(frame.rets.size)
            ]
            fn(_key(frame.attrs), inputs, outputs)
            return None
        except BaseException as error:  # noqa: BLE001 (XLA reports it; nothing may escape)
            return _error(frame, error)

    return ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_void_p)(call)


TARGET = "cfm_jax_host"
"""The XLA FFI target of :func:`host_call` (registered on CPU on first use)."""
_FUNCTIONS: dict[str, Callable] = {}  # key -> the host function the calls with that key run
_HANDLER = None  # the C function XLA calls, kept alive
_REGISTERED: bool | None = None


def _run(key: str, inputs: list, outputs: list) -> None:
    import jax

    results = jax.tree.leaves(_FUNCTIONS[key](*inputs))
    if len(results) != len(outputs):
        raise ValueError(f"{key}: {len(results)} results where the call declared {len(outputs)}")
    for out, value in zip(outputs, results, strict=True):
        out[...] = value


def registered() -> bool:
    """Registers :data:`TARGET` once per process; False where this JAX cannot (the callers
    then use ``jax.pure_callback``).

    Examples:
      >>> registered()  # jax.ffi on XLA:CPU
      True
    """
    global _HANDLER, _REGISTERED
    if _REGISTERED is None:
        import jax

        try:
            _HANDLER = _HANDLER or _handler(_run)  # one per process: XLA keeps its address
            jax.ffi.register_ffi_target(TARGET, jax.ffi.pycapsule(_HANDLER), platform="cpu")
            _REGISTERED = True
        except (AttributeError, TypeError, ValueError, RuntimeError):  # no such jax.ffi
            _REGISTERED = False
    return _REGISTERED


def here() -> bool:
    """Whether :func:`host_call` takes the FFI target here (XLA:CPU, :func:`registered`).

    Examples:
      >>> here()  # on a CPU
      True
    """
    import jax

    return jax.default_backend() == "cpu" and registered()


def host_call(key: str, fn: Callable, shapes, *args, fast: bool = True):
    """``fn(*args)`` on the host as a JAX operation (float32 in and out, no gradient; a
    ``vmap`` passes the whole batch in one call).

    Args:
      key: names everything ``fn`` computes from besides ``args`` (a model's bytes, gains):
        the program holds the key, not ``fn``, and the first ``fn`` given a key is the one
        every call with that key runs, in this process.
      fn: the host function, NumPy arrays in, a pytree of arrays out.
      shapes: its results' ``jax.ShapeDtypeStruct`` pytree (float32).
      args: the operands (float32).
      fast: on XLA:CPU, the FFI target :data:`TARGET` (programs JAX's cache keeps); False:
        ``jax.pure_callback`` (the same results).

    Examples:
      >>> import jax, jax.numpy as jnp
      >>> shape = jax.ShapeDtypeStruct((3,), jnp.float32)
      >>> double = lambda x: host_call("doubled", lambda a: 2 * a, shape, x)
      >>> jax.jit(jax.vmap(double))(jnp.ones((2, 3))).tolist()
      [[2.0, 2.0, 2.0], [2.0, 2.0, 2.0]]
    """
    import jax

    if fast and here():
        _FUNCTIONS.setdefault(key, fn)
        leaves, tree = jax.tree.flatten(shapes)
        call = jax.ffi.ffi_call(TARGET, leaves, vmap_method="broadcast_all")
        return jax.tree.unflatten(tree, call(*args, key=key))
    return jax.pure_callback(fn, shapes, *args, vmap_method="broadcast_all")
