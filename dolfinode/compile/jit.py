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
import logging
import threading
from contextlib import contextmanager, nullcontext

from numba import njit, types

logger = logging.getLogger("dolfinode")

#: njit options of the loops' helpers: numba's disk cache, and numpy's error model (as the
#: loops themselves): a division by zero gives inf or nan, which the loops check, instead of
#: raising ZeroDivisionError, whose check and raise every division carried into the compile.
HELPER = {"cache": True, "error_model": "numpy"}



def helper(**options):
    """``njit`` for the loops' helper functions (:data:`HELPER` and ``options``), compiled
    for argument types without literal values.

    Called from compiled code, numba compiles a function once more for every constant
    argument (``f(x, True)``, ``f(x, 1)``), and for the literal first value of a counter
    (``n = 0`` then ``n += 1``) that type inference meets before the counter's type: with
    empty caches the sweeps of the multi-adaptive loop were compiled twice, the band
    assembly of its Newton groups eight times."""
    def decorate(func):
        dispatcher = njit(**HELPER, **options)(func)
        typed = dispatcher.get_call_template

        def get_call_template(args, kws):
            return typed(tuple(types.unliteral(a) for a in args),
                         {name: types.unliteral(a) for name, a in kws.items()})

        dispatcher.get_call_template = get_call_template
        return dispatcher
    return decorate


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
    has not been compiled or loaded in this process yet, else a context that does nothing."""
    return nullcontext() if dispatcher.signatures else announced(what, seconds)


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
        if self._entry is None or Loop.checked:
            dispatcher = self.compile()
            if Loop.checked:
                return dispatcher(*args)
            self._entry = dispatcher.overloads[self.signature.args].entry_point
        return self._entry(*args)
