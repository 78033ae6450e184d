"""The time-slab loops, compiled on first use and announced when that takes a while.

A loop declared with an explicit numba signature is compiled when its module is imported:
the mono-adaptive loop alone took ~29 s of a 32 s ``import dolfinode`` with empty caches.
:class:`Loop` compiles it for that one signature on its first call instead (numba's disk
cache, ``cache=True``, makes that a load in every later process), and refuses other
argument types rather than compiling a second specialisation.

A compile that runs longer than :data:`NOTICE_AFTER` seconds is announced on the
``"dolfinode"`` logger at WARNING level (printed on stderr when logging is not configured);
silence it with ``logging.getLogger("dolfinode").setLevel(logging.ERROR)``.
"""
import ctypes
import functools
import hashlib
import importlib
import inspect
import logging
import threading
import types as pytypes
from contextlib import contextmanager, nullcontext

import llvmlite.binding as ll
import llvmlite.ir as llvm_ir
from numba import njit, types
from numba.core import cgutils
from numba.core.extending import _Intrinsic
from numba.core.registry import CPUDispatcher

logger = logging.getLogger("dolfinode")

#: njit options of the loops' helpers (with numba's disk cache): numpy's error model (as the
#: loops themselves): a division by zero gives inf or nan, which the loops check, instead of
#: raising ZeroDivisionError, whose check and raise every division carried into the compile.
#: Declared, not left to numba: a function without an error model takes that of the
#: compile it is first compiled in, the caller's or python's when compiled on its own
#: (a lazily linked routine): its divisions then carry the checks after all.
HELPER = {"error_model": "numpy"}


class _Callee(CPUDispatcher):
    """A numba function compiled for compiled callers only: without numba's CPython and C
    wrappers (``no_cpython_wrapper``, ``no_cfunc_wrapper``), which unbox and box every
    argument for a call from Python and which a compiled caller never uses. Lowered,
    optimised and turned into machine code, they were ~4 s of the cold start (a helper takes
    up to 40 arrays).

    Called from Python (tests, a driver) it runs a copy compiled with the wrappers, cached
    under its own name (``<qualname>_from_python``): numba's disk cache does not key an entry
    by these options, and the entry point of a function without them is null."""

    def __call__(self, *args, **kwargs):
        python = self.__dict__.get("_from_python")
        if python is None:
            f = self.py_func
            copy = pytypes.FunctionType(f.__code__, f.__globals__, f.__name__, f.__defaults__,
                                        f.__closure__)
            copy.__qualname__ = f"{f.__qualname__}_from_python"
            copy.__module__ = f.__module__
            options = {name: value for name, value in self.targetoptions.items()
                       if name not in _NO_WRAPPERS and name != "nopython"}
            python = self._from_python = njit(cache=True, **options)(copy)
        return python(*args, **kwargs)


#: The options that make a :class:`_Callee`.
_NO_WRAPPERS = {"no_cpython_wrapper": True, "no_cfunc_wrapper": True}


def callee(**options):
    """``njit(**options)`` for a function that compiled code calls (:class:`_Callee`):
    numba's disk cache (``cache=True``) is on."""
    def decorate(func):
        dispatcher = _Callee(py_func=func, locals={},
                             targetoptions={"nopython": True, **options, **_NO_WRAPPERS})
        dispatcher.enable_caching()
        return dispatcher
    return decorate


def helper(**options):
    """``njit`` for the loops' helper functions (:data:`HELPER` and ``options``, without the
    wrappers for calls from Python: :class:`_Callee`), compiled for argument types without
    literal values.

    Called from compiled code, numba compiles a function once more for every constant
    argument (``f(x, True)``, ``f(x, 1)``), and for the literal first value of a counter
    (``n = 0`` then ``n += 1``) that type inference meets before the counter's type: with
    empty caches the sweeps of the multi-adaptive loop were compiled twice, the band
    assembly of its Newton groups eight times."""
    def decorate(func):
        dispatcher = callee(**HELPER, **options)(func)
        typed = dispatcher.get_call_template

        def get_call_template(args, kws):
            return typed(tuple(types.unliteral(a) for a in args),
                         {name: types.unliteral(a) for name, a in kws.items()})

        dispatcher.get_call_template = get_call_template
        return dispatcher
    return decorate


class Linked(_Intrinsic):
    """A numba function that other compiled functions call through a symbol instead of
    linking its code into theirs.

    numba copies the LLVM IR of every function a compiled function calls into its module
    and optimises and compiles that module as a whole: a large routine (the slab's Newton
    iteration, a banded LU) is optimised and turned into machine code again in every caller,
    and their callers (doc/design/compile.md). Called through :class:`Linked`, it is
    compiled once per argument types (and cached by numba); the caller declares the symbol
    ``dolfinode.<module>.<name>.<hash of the types>``, which the JIT resolves to the
    compiled function (``llvmlite.binding.add_symbol``). The caller's library records the
    link as a reload hook, so a caller loaded from numba's disk cache links its callees
    (loading or compiling them) before its own code.

    With ``returns`` (its numba return type, declared so that a caller is typed without it)
    the routine is compiled on its first call instead of with its callers (:class:`_LazyLink`):
    the stiff solvers, which a non-stiff problem never calls.

    Called from Python, it calls the numba function. Wrap a dispatcher: ``@linked`` over
    ``@helper(...)``.
    """

    def __init__(self, dispatcher, returns=None, what=None, seconds=0.0):
        if "error_model" not in dispatcher.targetoptions:
            raise TypeError(f"linked {dispatcher.py_func.__qualname__}: declare its error model "
                            "(helper()), or it depends on what compiles it first")
        self.dispatcher = dispatcher
        key = f"{dispatcher.py_func.__module__}:{dispatcher.py_func.__qualname__}"

        def typer(typingctx, *args):
            args = tuple(types.unliteral(a) for a in args)
            if returns is not None:
                return returns(*args), functools.partial(_lazy_call, key, what, seconds)
            signature = _Link(key, args)()

            def codegen(context, builder, sig, llargs):
                link = _Link(key, sig.args, sig.return_type)
                link()  # the callee's symbol, before this library is finalized
                context.active_code_library._reload_init.add(link)
                function = cgutils.get_or_insert_function(
                    builder.module,
                    context.call_conv.get_function_type(sig.return_type, sig.args),
                    link.symbol)
                status, result = context.call_conv.call_function(
                    builder, function, sig.return_type, sig.args, llargs)
                with cgutils.if_unlikely(builder, status.is_error):
                    context.call_conv.return_status_propagate(builder, status)
                return result

            return signature, codegen

        # numba folds the call's arguments by the typer's parameters: the function's own
        parameters = inspect.signature(dispatcher.py_func).parameters.values()
        typer.__signature__ = inspect.Signature(
            [inspect.Parameter("typingctx", inspect.Parameter.POSITIONAL_OR_KEYWORD),
             *parameters])
        super().__init__(dispatcher.py_func.__name__, typer)
        functools.update_wrapper(self, dispatcher.py_func)  # its name and docstring
        self._register()

    def __call__(self, *args):
        return self.dispatcher(*args)

    @property
    def py_func(self):
        return self.dispatcher.py_func

    @property
    def signatures(self):
        return self.dispatcher.signatures

    def __repr__(self):
        return f"<linked {self._name}>"


#: symbol -> signature of the callees linked in this process
_LINKED = {}


class _Link:
    """The link of one callee (``key``: "module:qualname") for argument types ``args``:
    calling it compiles (or loads) the callee for them, registers its symbol (once per
    process) and returns the signature. Picklable: numba stores it with a caller's cache,
    with the ``return_type`` the caller was compiled for."""

    return_type = None

    def __init__(self, key, args, return_type=None):
        self.key = key
        self.args = tuple(args)
        self.return_type = return_type
        digest = hashlib.sha1(str(self.args).encode()).hexdigest()[:16]
        self.symbol = f"dolfinode.{key.replace(':', '.')}.{digest}"

    def __call__(self):
        if self.symbol not in _LINKED:
            module, qualname = self.key.split(":")
            callee = importlib.import_module(module)
            for name in qualname.split("."):
                callee = getattr(callee, name)
            dispatcher = getattr(callee, "dispatcher", callee)  # also if no longer linked
            dispatcher.compile(self.args)
            result = dispatcher.overloads[self.args]
            ll.add_symbol(self.symbol, result.library.get_pointer_to_function(
                result.fndesc.llvm_func_name))
            _LINKED[self.symbol] = result.signature
        signature = _LINKED[self.symbol]
        if self.return_type is not None and signature.return_type != self.return_type:
            raise RuntimeError(
                f"a caller of {self.key} expects it to return {self.return_type} (declared, "
                f"or cached), it returns {signature.return_type}: correct the declaration or "
                "clear numba's cache (NUMBA_CACHE_DIR)")
        return signature

    def __reduce__(self):
        return _Link, (self.key, self.args, self.return_type)

    def __eq__(self, other):
        return isinstance(other, _Link) and self.symbol == other.symbol

    def __hash__(self):
        return hash(self.symbol)


def _lazy_call(key, what, seconds, context, builder, sig, llargs):
    """The code of a call of a lazily linked routine: load its address from the slot,
    filling the slot first if it is empty (the resolver compiles the routine), and call it;
    a slot still empty (the compile failed, logged) raises RuntimeError."""
    link = _LazyLink(key, sig.args, sig.return_type, what, seconds)
    link()
    context.active_code_library._reload_init.add(link)
    function_type = context.call_conv.get_function_type(sig.return_type, sig.args)
    module = builder.module
    try:
        slot = module.get_global(link.slot)
    except KeyError:
        slot = llvm_ir.GlobalVariable(module, function_type.as_pointer(), link.slot)
    resolve = cgutils.get_or_insert_function(
        module, llvm_ir.FunctionType(llvm_ir.VoidType(), []), link.resolver)
    with builder.if_then(cgutils.is_null(builder, builder.load(slot)), likely=False):
        builder.call(resolve, [])
    function = builder.load(slot)
    with cgutils.if_unlikely(builder, cgutils.is_null(builder, function)):
        context.call_conv.return_user_exc(
            builder, RuntimeError, (f"dolfinode: compiling {key} failed (see the log)",))
    status, result = context.call_conv.call_function(
        builder, function, sig.return_type, sig.args, llargs)
    with cgutils.if_unlikely(builder, status.is_error):
        context.call_conv.return_status_propagate(builder, status)
    return result


#: slot symbol -> (link, slot, resolver) of the lazily linked callees registered in this
#: process
_SLOTS = {}
_RESOLVER = ctypes.CFUNCTYPE(None)
#: what the lazily linked compiles of this process have announced: once each (a routine's
#: real and complex specialisations are one notice)
_ANNOUNCED = set()


class _LazyLink:
    """The lazy link of one callee (``key``: "module:qualname") for argument types ``args``:
    calling it registers, once per process, the symbols ``<symbol>.slot``, a pointer to the
    compiled callee (null until its first call), and ``<symbol>.resolve``, a function that
    compiles or loads the callee (:class:`_Link`, announced as ``what`` when it takes a
    while) and fills the slot. A caller's code calls the resolver when it finds the slot
    empty. Picklable, stored with a caller's cache as :class:`_Link`."""

    def __init__(self, key, args, return_type, what=None, seconds=0.0):
        self.link = _Link(key, args, return_type)
        self.what = what or key
        self.seconds = seconds
        self.slot = self.link.symbol + ".slot"
        self.resolver = self.link.symbol + ".resolve"

    def __call__(self):
        if self.slot not in _SLOTS:
            slot = ctypes.c_void_p(0)
            resolver = _RESOLVER(functools.partial(self._resolve, slot))
            _SLOTS[self.slot] = (self, slot, resolver)
            ll.add_symbol(self.slot, ctypes.addressof(slot))
            ll.add_symbol(self.resolver, ctypes.cast(resolver, ctypes.c_void_p).value)

    def _resolve(self, slot):
        # (a ctypes callback cannot raise into the compiled caller: an empty slot tells it)
        try:
            notice = (nullcontext() if self.what in _ANNOUNCED
                      else announced(self.what, self.seconds))
            _ANNOUNCED.add(self.what)
            with notice:
                self.link()
            slot.value = ll.address_of_symbol(self.link.symbol)
        except Exception:
            logger.exception("dolfinode: compiling %s failed", self.link.key)

    def __reduce__(self):
        link = self.link
        return _LazyLink, (link.key, link.args, link.return_type, self.what, self.seconds)

    def __eq__(self, other):
        return isinstance(other, _LazyLink) and self.slot == other.slot

    def __hash__(self):
        return hash(self.slot)


def compile_pending():
    """Compile (or load) every lazily linked routine that the compiled functions of this
    process may call and have not called yet, and those their compiles link in turn (for
    ``dolfinode compile``); returns their names. Raises RuntimeError if one fails."""
    names = []
    pending = [entry for entry in _SLOTS.values() if not entry[1].value]
    while pending:
        for link, slot, _ in pending:
            link._resolve(slot)
            if not slot.value:
                raise RuntimeError(f"dolfinode: compiling {link.link.key} failed (see the log)")
            names.append(link.what)
        pending = [entry for entry in _SLOTS.values() if not entry[1].value]
    return names


def linked(dispatcher=None, *, returns=None, what=None, seconds=0.0):
    """Decorator: the numba ``dispatcher`` called through a symbol (:class:`Linked`);
    ``@linked(returns=..., what=..., seconds=...)``: compiled on its first call, announced as
    ``what`` (about ``seconds``)."""
    if dispatcher is None:
        return functools.partial(Linked, returns=returns, what=what, seconds=seconds)
    return Linked(dispatcher)


#: Seconds after which a compile still running is announced (a load from numba's disk cache
#: takes well under a second).
NOTICE_AFTER = 2.0


@contextmanager
def announced(what, seconds):
    """Run the block, logging "dolfinode: compiling {what} once (about {seconds} s); it is
    cached afterwards" if it is still running after :data:`NOTICE_AFTER` seconds."""
    message = (f"dolfinode: compiling {what} once (about {seconds:.0f} s); it is cached "
               "afterwards")
    timer = threading.Timer(NOTICE_AFTER, logger.warning, args=(message,))
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


def first_use(dispatcher, what, seconds):
    """:func:`announced` if the numba ``dispatcher`` (one of the functions a block compiles)
    has not been compiled or loaded in this process yet (a helper called from Python: its
    copy, :class:`_Callee`), else a context that does nothing."""
    python = dispatcher.__dict__.get("_from_python")
    # (``overloads``, not ``signatures``: its list cost 5-9 us, a third of a dense evaluation)
    compiled = dispatcher.overloads or (python is not None and python.overloads)
    return nullcontext() if compiled else announced(what, seconds)


class Loop:
    """A numba function compiled for one ``signature`` on its first call.

    ``Loop.checked = True`` makes :meth:`unchecked` calls type-checked (for tests).

    Parameters
    ----------
    py_func : callable
        The Python function (module level, so numba's disk cache can find it).
    signature : numba signature
    what : str
        Its name in the compile notice ("the multi-adaptive loop").
    seconds : float
        Typical compile time, for the notice.
    **options
        numba ``njit`` options (``cache=True`` is added).
    """

    checked = False

    def __init__(self, py_func, signature, what, seconds, **options):
        self.py_func = py_func
        self.signature = signature
        self.what = what
        self.seconds = seconds
        self.options = dict(options, cache=True)
        self._dispatcher = None
        self._entry = None
        self.__doc__ = py_func.__doc__

    @property
    def is_compiled(self):
        """Whether this process has compiled (or loaded) the loop already."""
        return self._dispatcher is not None

    def compile(self):
        """The numba dispatcher, compiled (or loaded from the disk cache) on the first call."""
        if self._dispatcher is None:
            dispatcher = njit(**self.options)(self.py_func)
            with announced(self.what, self.seconds):
                dispatcher.compile(self.signature)
            dispatcher.disable_compile()
            self._dispatcher = dispatcher
        return self._dispatcher

    def __call__(self, *args):
        return (self._dispatcher or self.compile())(*args)

    def unchecked(self, *args):
        """Call the compiled code without numba's type dispatch (which typed the ~26 arguments
        of a loop in ~10 us, most of a small solve). Its wrapper does not check dtypes: for
        callers that build every argument with the signature's types (the drivers; tests run
        them through the checked call with ``Loop.checked = True``)."""
        entry = self._entry
        if entry is None or Loop.checked:
            entry = self.entry()
        return entry(*args)

    def entry(self):
        """What :meth:`unchecked` calls: the compiled entry point (the type-checked
        dispatcher while ``Loop.checked``), for a caller that keeps it over many calls (a prepared
        solve is a few microseconds: the lookup would be a large part of it)."""
        if Loop.checked:
            return self.compile()
        if self._entry is None:
            self._entry = self.compile().overloads[self.signature.args].entry_point
        return self._entry
