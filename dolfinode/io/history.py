"""Where the elements a solve stores go as the time-slab loop produces them: its *history*.

The driver (:func:`dolfinode.solve._integrate`) hands each chunk of stored elements to a sink
and, at the end, asks the sink for the :class:`~dolfinode.Solution`. The parameter
``dense_output`` chooses it (as scipy's ``dense_output``, diffrax's ``SaveAt``):

- True (:class:`InMemory`): the whole history in memory, checked against the memory
  available to the process after each chunk, so that a history that would not fit stops
  with a SolverError naming ``dense_output`` instead of numpy's MemoryError or the OOM killer;
- False (:class:`Samples`): each chunk is evaluated at the sample times it covers and
  dropped (a multi-adaptive dense value once the few slabs it reads are in, :class:`Window`);
  the memory does not grow with the number of steps;
- a path "run.h5" (:class:`dolfinode.io.stored.ToFile`): each chunk is appended to an HDF5
  file, which :func:`dolfinode.load_solution` opens lazily.

A chunk is ``[t_start (n,), k (n,), values (n, q + 1, N)]`` from a mono-adaptive loop (a
shared partition) and ``[comp (n,), t_start (n,), t_end (n,), values (n, q + 1), s_start (S,),
s_end (S,), s_values (S, (q + 1) N)]`` from a multi-adaptive one, each element covering
(t_start, t_end] (the value at a shared end point is the left element's, as
:class:`~dolfinode.Solution` returns), and each slab on which every component took one element
of one interval stored as a block, its values (q + 1, N) row-major (:func:`filled` cuts a
chunk from the loop's buffers; :func:`as_elements` spells the blocks out by element).
"""
import ctypes
import ctypes.util
import mmap
from functools import cached_property

import numpy as np
from numba import njit

from dolfinode.errors import OutOfMemoryError
from dolfinode.memory import address_space_room, available_memory
from dolfinode.solution import (
    MixedSolution,
    Solution,
    _correction,
    _dense_value,
    _group,
    _locate,
    _set_initial,
    branches_taken,
    correct_multi,
    dense_rhs,
    dense_rule,
    equispaced,
    evaluate_mono,
    join_elements,
    on_branches,
    transposed,
)
from dolfinode.timeslab import STORED, STORED_BLOCKS

#: A dense history is checked against the available memory once it holds this many bytes
#: (reading /proc for every chunk of a small solve would cost more than it guards).
CHECK_FROM = 2**26
#: A buffer of more bytes whose chunk fills less than half of it is copied (:func:`filled`).
SHORT_CHUNK = 2**16


def filled(buffers, counters):
    """The chunk a loop call stored in its output ``buffers``: their first counters[STORED]
    rows, and of a multi-adaptive loop's block buffers (its last three of seven) the first
    counters[STORED_BLOCKS]."""
    n = counters[STORED]
    if len(buffers) == 7:
        blocks = counters[STORED_BLOCKS]
        return [_cut(b, n) for b in buffers[:4]] + [_cut(b, blocks) for b in buffers[4:]]
    return [_cut(b, n) for b in buffers]


def _cut(buffer, n):
    """The first n rows of ``buffer``: a copy where they fill less than half of a large
    buffer, so that many short chunks (the pieces between breakpoints or events) do not each
    keep a whole buffer alive."""
    if 2 * n < len(buffer) and buffer.nbytes > SHORT_CHUNK:
        return buffer[:n].copy()
    return buffer[:n]


def as_elements(chunk, N):
    """A multi-adaptive ``chunk`` as its elements [comp, t_start, t_end, values (n, q + 1)]:
    each block spelt out as N elements (component i on the block's interval, its values
    column i), after the others."""
    comp, t_start, t_end, values, s_start, s_end, s_values = chunk
    S, nn = s_start.size, values.shape[1]
    if S == 0:
        return chunk[:4]
    return [np.concatenate([comp, np.tile(np.arange(N), S)]),
            np.concatenate([t_start, np.repeat(s_start, N)]),
            np.concatenate([t_end, np.repeat(s_end, N)]),
            np.concatenate([values, s_values.reshape(S, nn, N).transpose(0, 2, 1)
                            .reshape(S * N, nn)])]


def check_sample_times(ode, times):
    """Raise ValueError for ``sample_times`` (None or increasing times) outside [t0, T]."""
    if times is not None and (times[0] < ode.t0 or times[-1] > ode.T):
        raise ValueError(f"sample_times must lie in [t0, T] = [{ode.t0}, {ode.T}], got "
                         f"[{times[0]}, {times[-1]}]")


def sink(ode, method, multi_adaptive, params, restarts=None):
    """The history sink that ``params["dense_output"]`` asks for, with the sample times;
    ``restarts``: the list of (t, sigma) the solve's restarts fill (the branches of f's
    switches, :meth:`dolfinode.events.Plan.report`) before it adds the chunks, read by the
    dense values of the samples of ``dense_output=False``.

    Raises
    ------
    ValueError
        For sample times outside [t0, T].
    """
    times = params["sample_times"]
    if (params["estimate_global_error"] is True and multi_adaptive
            and params["dense_output"] is not True):
        raise ValueError("estimate_global_error=True with mcG(q)/mdG(q) propagates every "
                         "element's error to T on the common slabs of all components, which "
                         "needs the steps: drop dense_output (or set it True), or solve by "
                         "cG(q)/dG(q), whose error is estimated chunk by chunk without them")
    check_sample_times(ode, times)
    if params["dense_output"] is False:
        if times is None:
            times = equispaced(ode.t0, ode.T, params["number_of_samples"])
        return Samples(ode, method, multi_adaptive, times, restarts)
    if params["dense_output"] is True:
        return InMemory(ode, multi_adaptive, params["number_of_samples"] if times is None
                        else times)
    from dolfinode.io.stored import ToFile

    return ToFile(params["dense_output"], ode, method, multi_adaptive,
                  params["number_of_samples"] if times is None else times, restarts)


class Estimating:
    """A ``sink`` without history (:class:`Samples`, ToFile) of a mono-adaptive run that
    hands each chunk to ``running`` as well (:class:`dolfinode.global_error.Running`), so
    that the error at T is estimated as from the whole history; the Solution keeps it as
    ``_running_estimate``."""

    def __init__(self, sink, running):
        self.sink, self.running = sink, running

    def add(self, chunk, t):
        self.running.add(*chunk)
        self.sink.add(chunk, t)

    def finish(self, completed):
        return self.sink.finish(completed)

    def solution(self, ode, method, elements, stats, final):
        sol = self.sink.solution(ode, method, elements, stats, final)
        sol._running_estimate = self.running
        return sol


class InMemory:
    """``dense_output=True``: every chunk kept, joined into the Solution's arrays at the end.

    Multi-adaptive chunks are joined grouped by component (a counting sort as they are
    copied), so that the Solution is built without a global sort: the join peaks at the
    history plus one chunk, the Solution at 1.2 x the history (a lexsort with reordered
    copies peaked at 2.35 x). The blocks (slabs with every component on one interval) are
    kept as shared slabs, their values (q + 1, N) (a
    :class:`~dolfinode.solution.MixedSolution`).
    """

    def __init__(self, ode, multi_adaptive, samples):
        self.ode, self.multi_adaptive, self.samples = ode, multi_adaptive, samples
        self.chunks = []
        self.bytes = 0
        self.per_component = np.zeros(ode.N, dtype=np.int64) if multi_adaptive else None
        # (multi-adaptive) the elements outside blocks, per component
        self.elements_left = np.zeros(ode.N, dtype=np.int64) if multi_adaptive else None
        # (multi-adaptive) each component's last end and end value, read by mdG(q)'s dense value
        self.last_end = np.full(ode.N, float(ode.t0))
        self.last_value = np.array(ode.u0, dtype=float)
        # (mono-adaptive) the last chunk's end and end value, read by dG(q)'s dense value
        self.end, self.before = ode.t0, ode.u0

    def add(self, chunk, t):
        """Keep ``chunk`` (views of the loop's buffers, which it keeps alive); raise
        SolverError when the history reached at the time ``t`` leaves no room for more."""
        self.chunks.append(chunk)
        if self.multi_adaptive:
            _count_elements(chunk[0], len(chunk[4]), self.per_component, self.elements_left)
        # (a buffer the loop wrote into is kept whole)
        size = sum(part.nbytes if part.base is None else part.base.nbytes for part in chunk
                   if len(part))
        self.bytes += size
        if self.bytes >= CHECK_FROM:
            self._check_room(2 * size, t)

    def _check_room(self, more, t):
        """Raise SolverError if ``more`` bytes (the next buffers and the join's slack) do not
        fit; under RLIMIT_AS, where the join reserves its whole result at once, the history
        must fit a second time as well."""
        room, address_space = available_memory(), address_space_room()
        if address_space is not None:
            more += self.bytes
        if room >= more:
            return
        ode = self.ode
        done = (t - ode.t0) / (ode.T - ode.t0)
        projected = (f"; the whole interval would take about {self.bytes / done / 2**30:.3g} GB"
                     if done > 0 else "")
        raise OutOfMemoryError(
            f"the solution history kept for dense output has grown to "
            f"{self.bytes / 2**30:.3g} GB at t = {t:.6g} ({100 * done:.3g}% of [t0, T])"
            f"{projected}; going on and joining it needs {more / 2**30:.3g} GB more, and the "
            f"memory left to this process is {room / 2**30:.3g} GB (the least of the machine's "
            "available memory, its cgroup limit and RLIMIT_AS). Solve with dense_output=False "
            "to keep only the samples (choose them with sample_times=) and the final state",
            t=t)

    def finish(self, completed):
        """The joined elements: [t_start, k, values] as Solution takes them, or (multi-
        adaptive) [ptr, t_start, t_end, values] as Solution.grouped does and the synchronised
        slabs [s_start, s_end, s_values (S, q + 1, N)]."""
        if not completed:  # a failed solve: the elements are not used
            self.chunks.clear()
            return None
        if not self.multi_adaptive:
            return join_elements(self.chunks)
        N = self.ode.N
        ptr = np.zeros(N + 1, dtype=np.int64)
        np.cumsum(self.elements_left, out=ptr[1:])
        S = sum(len(chunk[4]) for chunk in self.chunks)
        large = self.bytes >= CHECK_FROM  # (a small join is not worth the system calls)
        empty = _small_pages if large else np.empty
        joined = [empty((ptr[-1], *part.shape[1:]), part.dtype) for part in self.chunks[0][1:4]]
        nn = joined[2].shape[1]
        slabs = [np.empty(S), np.empty(S), empty((S, nn, N), joined[2].dtype)]
        cursor = ptr[:-1].copy()
        n = 0  # (the next slab)
        self.chunks.reverse()
        while self.chunks:  # each chunk released once copied
            comp, t_start, t_end, values, s_start, s_end, s_values = self.chunks.pop()
            _scatter_by_component(comp, t_start, t_end, values, cursor, *joined)
            blocks = len(s_start)
            slabs[0][n:n + blocks], slabs[1][n:n + blocks] = s_start, s_end
            slabs[2][n:n + blocks] = s_values.reshape(blocks, nn, N)
            n += blocks
            del comp, t_start, t_end, values, s_start, s_end, s_values
            if large:
                _return_freed_memory()
        return [ptr, *joined, *slabs]

    def solution(self, ode, method, elements, stats, final):
        """The Solution of the joined ``elements`` (``final``: the state at T, unused)."""
        if not self.multi_adaptive:
            return Solution(ode, method, *elements, stats, self.samples)
        ptr, t_start, t_end, values, s_start, s_end, s_values = elements
        if _in_time_order(ptr, t_start) and np.all(s_start[1:] > s_start[:-1]):
            if s_start.size == 0:
                return Solution.grouped(ode, method, *elements[:4], stats, self.samples)
            return MixedSolution(ode, method, elements[:4], elements[4:], stats, self.samples)
        # the loop made a component's elements or its slabs out of order: sorted, as elements
        N, S = ode.N, s_start.size
        comp = np.concatenate([np.repeat(np.arange(N), np.diff(ptr)), np.tile(np.arange(N), S)])
        return Solution.multi_adaptive(
            ode, method, comp, np.concatenate([t_start, np.repeat(s_start, N)]),
            np.concatenate([t_end, np.repeat(s_end, N)]),
            np.concatenate([values, s_values.transpose(0, 2, 1).reshape(S * N, -1)]), stats,
            self.samples)


def _small_pages(shape, dtype):
    """np.empty(shape, dtype) in memory that is committed page by page as it is written.

    NumPy asks for transparent huge pages (2 MB) for large arrays: each chunk of a join by
    component writes a short run into every component's range, which with huge pages made
    the whole result resident at the first chunk (the join peaked at twice the history)."""
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize
    if size == 0 or not hasattr(mmap, "MADV_NOHUGEPAGE"):
        return np.empty(shape, dtype)
    memory = mmap.mmap(-1, size)
    memory.madvise(mmap.MADV_NOHUGEPAGE)
    return np.frombuffer(memory, dtype=dtype).reshape(shape)


def _return_freed_memory():
    """Give the heap's free pages back to the system (glibc's malloc_trim): buffers below
    malloc's mmap threshold (32 MB at most) stay resident when freed, and a join that
    copies them into new arrays would peak at twice the history."""
    if _libc is not None:
        _libc.malloc_trim(0)


def _load_libc():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.malloc_trim  # noqa: B018 - glibc only
        return libc
    except (OSError, AttributeError):
        return None


_libc = _load_libc()


@njit(cache=True)
def _in_time_order(ptr, t_start):
    """Whether each component's elements ptr[i]:ptr[i + 1] start in increasing time."""
    for i in range(ptr.shape[0] - 1):
        for e in range(ptr[i] + 1, ptr[i + 1]):
            if t_start[e] < t_start[e - 1]:
                return False
    return True


@njit(cache=True)
def _count_elements(comp, blocks, per_component, elements_left):
    """Count a chunk's elements (components ``comp``) and its ``blocks`` (every component
    once) in ``per_component``, the elements alone in ``elements_left``."""
    for e in range(comp.shape[0]):
        per_component[comp[e]] += 1
        elements_left[comp[e]] += 1
    for i in range(per_component.shape[0]):
        per_component[i] += blocks


@njit(cache=True)
def _scatter_by_component(comp, t_start, t_end, values, cursor, out_start, out_end,
                          out_values):
    """Copy a chunk's elements to their component's next free places (``cursor[i]``): a
    stable counting sort by component."""
    for e in range(comp.shape[0]):
        i = comp[e]
        n = cursor[i]
        out_start[n], out_end[n] = t_start[e], t_end[e]
        # by element: a slice assigned from an array compiles numba's long shape-error message
        for m in range(values.shape[1]):
            out_values[n, m] = values[e, m]
        cursor[i] = n + 1


@njit(cache=True)
def _sample_chunk(comp, t_start, t_end, values, s_start, s_end, s_values, order, nodes, bary,
                  dense, times, last_end, last_value, out):
    """out[i, m] = U_i(times[m]) for the times in (start, end] of each element (component
    comp[e]) and block (values (q + 1) N row-major) of a multi-adaptive chunk, by
    solution._dense_value. The chunk is walked in start time order (``order``: the elements
    by start time) so that the value before each is the end value of component i's previous
    one when it ends there: last_end[i], last_value[i] (t0, u0 before the first chunk),
    carried from chunk to chunk. The same bits as a Solution of the whole history."""
    N = out.shape[0]
    q1 = nodes.shape[0]
    p = 0
    n = 0
    while p < order.shape[0] or n < s_start.shape[0]:
        if n < s_start.shape[0] and (p == order.shape[0] or s_start[n] <= t_start[order[p]]):
            first = np.searchsorted(times, s_start[n], side="right")
            last = np.searchsorted(times, s_end[n], side="right")
            by_component = s_values[n].reshape((q1, N)).T
            for i in range(N):
                c = _correction(by_component, i, last_value[i] if last_end[i] == s_start[n]
                                else np.nan, dense)
                for m in range(first, last):
                    tau = (times[m] - s_start[n]) / (s_end[n] - s_start[n])
                    out[i, m] = _dense_value(by_component, i, tau, nodes, bary, c)
                last_end[i], last_value[i] = s_end[n], by_component[i, q1 - 1]
            n += 1
            continue
        e = order[p]
        i = comp[e]
        c = _correction(values, e, last_value[i] if last_end[i] == t_start[e] else np.nan,
                        dense)
        first = np.searchsorted(times, t_start[e], side="right")
        last = np.searchsorted(times, t_end[e], side="right")
        for m in range(first, last):
            tau = (times[m] - t_start[e]) / (t_end[e] - t_start[e])
            out[i, m] = _dense_value(values, e, tau, nodes, bary, c)
        last_end[i], last_value[i] = t_end[e], values[e, q1 - 1]
        p += 1


#: How many elements deep a multi-adaptive dense value reads around its own (its
#: neighbours' polynomials, their collocation coefficients, V's test, each neighbour's
#: neighbours; one more for the value before an element): :class:`Window`'s reach.
READ_DEPTH = 6


@njit(cache=True)
def _reach(ptr, t_start, t_end, x, depth, forward):
    """Where the elements read around x reach, ``depth`` elements deep (component i's
    elements ptr[i]:ptr[i + 1], time-sorted, each covering every time up to x): forward,
    the latest time y <= x whose reads end at or before x (each step: the start of every
    element holding x that ends after it); back, the earliest start of what times >= x
    read (each step: the start of every element holding x)."""
    for _ in range(depth):
        y = x
        for i in range(ptr.shape[0] - 1):
            if ptr[i + 1] > ptr[i]:
                e = ptr[i] + _locate(t_end[ptr[i]:ptr[i + 1]], x, 0)
                if not forward or t_end[e] > x:
                    y = min(y, t_start[e])
        x = y
    return x


class Window:
    """The multi-adaptive elements that the dense values of pending samples read
    (:func:`dolfinode.solution.correct_multi`), for ``dense_output=False``: each chunk's
    elements are added (blocks spelt out, :func:`as_elements`), the samples whose reads the
    stored elements cover (:func:`_reach` forward from the time every component has
    reached) are corrected, and the elements no later sample reads are dropped. It holds
    the elements READ_DEPTH deep around the next pending sample and those after: a few
    slabs, more while a component's element is still open (a frozen component's is stored
    when it wakes up, and the samples in it wait for it)."""

    def __init__(self, ode, method, compiled):
        self.ode, self.method, self.compiled = ode, method, compiled
        self.dependents = transposed(compiled.indptr, compiled.indices)
        self.elements = [np.empty(0, dtype=np.int64), np.empty(0), np.empty(0),
                         np.empty((0, method.q + 1))]
        self.next = 0  # (the first sample not yet corrected)

    def add(self, chunk, reached, times, out, branches=None):
        """Add ``chunk``'s elements and correct the samples out[:, m] at ``times`` that they
        now cover (``reached``: the time up to which every component's elements are in), f
        read on the ``branches`` the solve took (:func:`on_branches`)."""
        N = self.ode.N
        comp, t_start, t_end, values = (np.concatenate(parts) for parts in zip(
            self.elements, as_elements(chunk, N)))
        ptr, t_start, t_end, values = _group(N, comp, t_start, t_end, values)
        comp = np.repeat(np.arange(N), np.diff(ptr))
        ready = _reach(ptr, t_start, t_end, reached, READ_DEPTH, True)
        last = np.searchsorted(times, ready, side="right")
        if last > self.next:
            none = np.empty(0)
            history = (ptr, t_start, t_end, values, none, none, np.empty((0, values.shape[1], N)))
            on_branches(branches, times[self.next:last], out[:, self.next:last], self.compiled,
                        lambda at, rhs, part: correct_multi(self.method, rhs, self.dependents,
                                                            self.ode, history, at, part))
            self.next = last
        start = min(reached, times[self.next]) if self.next < times.size else reached
        keep = t_end >= _reach(ptr, t_start, t_end, start, READ_DEPTH, False)
        self.elements = [comp[keep], t_start[keep], t_end[keep], values[keep]]


class Samples:
    """``dense_output=False``: each chunk evaluated at the sample times it covers, then
    dropped (memory: the samples and one chunk, whatever the number of steps; the dense
    value of mcG(q), q >= 2, and mdG(q), q >= 1, also the few slabs of elements it reads,
    :class:`Window`)."""

    def __init__(self, ode, method, multi_adaptive, times, restarts=None):
        self.ode, self.method, self.multi_adaptive, self.times = ode, method, multi_adaptive, times
        self.restarts = restarts  # (see :func:`sink`)
        self.y = np.empty((times.size, ode.N)).T  # components contiguous, as Solution's y
        self.y.fill(np.nan)
        _set_initial(times, ode.t0, ode.u0, self.y)  # U(t0) = u0, as Solution's
        self.per_component = np.zeros(ode.N, dtype=np.int64) if multi_adaptive else None
        # (multi-adaptive) the elements outside blocks, per component
        self.elements_left = np.zeros(ode.N, dtype=np.int64) if multi_adaptive else None
        # (multi-adaptive) each component's last end and end value, read by mdG(q)'s dense value
        self.last_end = np.full(ode.N, float(ode.t0))
        self.last_value = np.array(ode.u0, dtype=float)
        # (mono-adaptive) the last chunk's end and end value, read by dG(q)'s dense value
        self.end, self.before = ode.t0, ode.u0
        # (the dense value of cG(q), dG(q), mcG(q), mdG(q))
        self.rhs = dense_rhs(method, ode, restarts is not None)
        self.window = (Window(ode, method, self.rhs) if multi_adaptive and self.rhs is not None
                       else None)

    def add(self, chunk, t):
        nodes, bary = self.method.nodes, self.method.barycentric_weights
        if self.multi_adaptive:
            _count_elements(chunk[0], len(chunk[4]), self.per_component, self.elements_left)
            order = np.argsort(chunk[1], kind="stable")
            _sample_chunk(*chunk, order, nodes, bary, dense_rule(self.method), self.times,
                          self.last_end, self.last_value, self.y)
            if self.window is not None:
                self.window.add(chunk, self.last_end.min(), self.times, self.y, self.branches)
            return
        t_start, k, values = chunk
        if t_start.shape[0] == 0:
            return
        t_end = t_start + k
        first = np.searchsorted(self.times, t_start[0], side="right")
        last = np.searchsorted(self.times, t_end[-1], side="right")
        # the chunk's first element reads the previous end value where it continues it, as
        # the Solution of the whole history does (solution._evaluate_dg)
        joined = abs(self.end - t_start[0]) <= 4e-16 * abs(t_start[0])
        on_branches(self.branches, self.times[first:last], self.y[:, first:last], self.rhs,
                    lambda at, rhs, part: evaluate_mono(
                        self.method, t_start, t_end, values, [t_start[0]] if joined else [],
                        [self.before] if joined else [], at, part, rhs))
        self.end, self.before = t_end[-1], values[-1, -1].copy()

    @cached_property
    def branches(self):
        """The branches the solve took (:func:`branches_taken`; None without switches), read
        once its restarts are in: at the first chunk added."""
        return None if self.restarts is None else branches_taken(self.restarts)

    def finish(self, completed):
        return None

    def solution(self, ode, method, elements, stats, final):
        """A :class:`SampledSolution` of the samples and the state at T, ``final``."""
        return SampledSolution(ode, method, self.times, self.y, final.copy(), stats)


#: What a solution without history says when asked for it.
NEEDS_HISTORY = ("this solution kept only its samples and final state (dense_output=False); "
                 "{what} needs the history: solve with dense_output=True")


class SampledSolution(Solution):
    """A solution that kept only its samples ``t``, ``y`` and the state at T, ``final``
    (``dense_output=False``): it is evaluated at those times only."""

    dense = False

    def __init__(self, ode, method, times, y, final, stats):
        self.ode, self.method, self.stats = ode, method, stats
        self.t_start = self.k = self.values = None
        self._component_ptr = None
        self.__dict__["t"], self.__dict__["y"] = times, y
        self.final = final

    def _values(self, times):
        """U at sample times (or T), else ValueError."""
        at = np.minimum(np.searchsorted(self.t, times), self.t.size - 1)
        known = self.t[at] == times
        out = self.y[:, at]
        at_end = times == self.ode.T
        out[:, at_end] = self.final[:, None]
        missing = ~(known | at_end)
        if missing.any():
            raise ValueError(NEEDS_HISTORY.format(
                what=f"U(t) at t = {times[missing][0]:.17g}, which is not a sample time,"))
        return out

    def time_steps(self, component=None):
        raise ValueError(NEEDS_HISTORY.format(what="time_steps()"))

    def elements(self):
        raise ValueError(NEEDS_HISTORY.format(what="elements()"))

    def __repr__(self):
        return (f"SampledSolution({self.method.name}, N={self.ode.N}, samples={self.t.size}, "
                f"t=[{self.ode.t0}, {self.ode.T}])")
