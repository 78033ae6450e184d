"""A solution history streamed to an HDF5 file (``dense_output="run.h5"``) and read back
lazily (:func:`load_solution`).

The file holds the elements as the loop stored them: ``t_start``, ``k`` (M,) and ``values``
(M, q + 1, N) of a shared partition, or ``comp``, ``t_start``, ``t_end`` (E,) and ``values``
(E, q + 1) of a multi-adaptive one, and the declaration as solved (pickled: open only files
you trust, as with any pickle). It is written without a name and named when complete
(:func:`dolfinode.io.atomic.new_file`): a failed or killed solve leaves no file.
:func:`load_solution` reads the element times at the first evaluation and only the nodal values
that an evaluation needs.
"""
import contextlib
import pickle
import weakref
from functools import cached_property

import numpy as np

from dolfinode.io.atomic import new_file
from dolfinode.io.history import as_elements
from dolfinode.methods import parse_method
from dolfinode.solution import (
    Solution,
    _defect_check,
    _evaluate_components,
    branches_taken,
    dense_rule,
    evaluate_mono,
    on_branches,
)

#: The format's name and version, checked when a file is opened.
FORMAT, VERSION = "dolfinode solution history", 1
_MONO = ("t_start", "k", "values")
_MULTI = ("comp", "t_start", "t_end", "values")
#: The branches of f's switches the solve took (:func:`dolfinode.solution.branches_taken`).
_BRANCHES = ("branch_starts", "branch_sigmas")


def _h5py():
    try:
        import h5py
    except ImportError:  # pragma: no cover - h5py is a dependency
        raise ImportError("dense_output to a file and load_solution need h5py: "
                          "pip install h5py") from None
    return h5py


def bound_metadata_cache(h5, size=2**21):
    """Fix HDF5's metadata cache of the open file ``h5`` at ``size`` bytes: by default it
    grows with the datasets and chunks written (4.7 kB per dataset), so that the memory of
    a long write grows with its steps; fixed, it levels off (near 15 MB for 20000
    datasets)."""
    config = h5.id.get_mdc_config()
    config.set_initial_size, config.initial_size = True, size // 2
    config.min_size, config.max_size = size // 2, size
    config.incr_mode = config.decr_mode = config.flash_incr_mode = 0  # (off)
    h5.id.set_mdc_config(config)


class ToFile:
    """``dense_output="run.h5"``: each chunk appended to the file; the Solution reads it
    back lazily (memory: one chunk, whatever the number of steps)."""

    def __init__(self, path, ode, method, multi_adaptive, samples, restarts=None):
        self.path, self.ode, self.multi_adaptive, self.samples = path, ode, multi_adaptive, samples
        self.restarts = restarts  # (:func:`dolfinode.io.history.sink`'s)
        self.per_component = np.zeros(ode.N, dtype=np.int64) if multi_adaptive else None
        self._writing = new_file(path)
        file = self._writing.__enter__()
        try:
            self.h5 = _h5py().File(file, "w")
        except BaseException:
            _drop(self._writing)
            raise
        # an exception in the loop (KeyboardInterrupt, MemoryError) drops the file when the
        # sink is collected, or at exit: HDF5 closed first, then the file under it
        self._finalizer = weakref.finalize(self, _drop, self._writing, self.h5)
        bound_metadata_cache(self.h5)
        self.h5.attrs.update(format=FORMAT, version=VERSION, complete=False,
                             method=("m" if multi_adaptive else "") + method.name)
        self.datasets = None

    def add(self, chunk, t):
        if self.multi_adaptive:  # (the file keeps one element per row)
            chunk = as_elements(chunk, self.ode.N)
        if self.datasets is None:
            # chunks of about 1 MB: h5py's guess for a dataset that starts empty is small,
            # and the chunk index grows with their number
            self.datasets = [self.h5.create_dataset(
                name, shape=(0, *part.shape[1:]), maxshape=(None, *part.shape[1:]),
                dtype=part.dtype,
                chunks=(max(1, 2**20 // (part[:1].nbytes or 1)), *part.shape[1:]))
                             for name, part in zip(_MULTI if self.multi_adaptive else _MONO,
                                                   chunk)]
        for dataset, part in zip(self.datasets, chunk):
            n = dataset.shape[0]
            dataset.resize(n + len(part), axis=0)
            dataset[n:] = part
        if self.multi_adaptive:
            self.per_component += np.bincount(chunk[0], minlength=self.ode.N)

    def finish(self, completed):
        if not completed:
            self.abandon()

    def solution(self, ode, method, elements, stats, final):
        """Complete the file (with the declaration and stats) and open it lazily."""
        try:
            self.h5.create_dataset("declaration", data=np.void(pickle.dumps(ode)))
            self.h5.create_dataset("stats", data=np.void(pickle.dumps(stats)))
            if self.restarts is not None:  # (the branches the dense values read f on)
                for name, part in zip(_BRANCHES, branches_taken(self.restarts)):
                    self.h5.create_dataset(name, data=part)
            self.h5.attrs["complete"] = True
            self.h5.close()
        except BaseException:
            self.abandon()
            raise
        self._finalizer.detach()
        self._writing.__exit__(None, None, None)
        return load_solution(self.path, self.samples)

    def abandon(self):
        """Close and drop the unfinished file (a failed solve)."""
        self._finalizer()


def _drop(writing, h5=None):
    """Close ``h5`` and leave the file of :func:`new_file` under it unnamed (or remove its
    temporary name)."""
    if h5 is not None:
        with contextlib.suppress(Exception):
            h5.close()
    with contextlib.suppress(Exception):
        writing.__exit__(RuntimeError, RuntimeError("the solve did not complete"), None)


def load_solution(path, number_of_samples=101):
    """Open a solution history written by ``solve(..., dense_output=path)``.

    ``sol(t)``, ``sol.y`` read the elements around their times only (of a shared partition,
    their times too, by blocks; a multi-adaptive history reads its element times at the
    first evaluation); ``sol.t_start``, ``sol.values``, ``elements()`` and error estimates
    read them all.

    Parameters
    ----------
    path : str or os.PathLike
    number_of_samples : int or array, optional
        The samples ``sol.t``, ``sol.y`` (equispaced, or these times).

    Raises
    ------
    ValueError
        Naming the file when it is not a complete dolfinode history.
    """
    h5 = _h5py().File(path, "r")
    try:
        if h5.attrs.get("format") != FORMAT or h5.attrs.get("version") != VERSION:
            raise ValueError(f"{path} is not a dolfinode solution history (written by "
                             "solve(..., dense_output='run.h5'))")
        if not h5.attrs.get("complete"):
            raise ValueError(f"{path} is an incomplete dolfinode solution history")
        ode = pickle.loads(h5["declaration"][()].tobytes())
        stats = pickle.loads(h5["stats"][()].tobytes())
        multi, method = parse_method(h5.attrs["method"])
    except BaseException:
        h5.close()
        raise
    sol = StoredSolution.__new__(StoredSolution)
    sol.ode, sol.method, sol.stats, sol.path, sol._h5 = ode, method, stats, str(path), h5
    sol._stored, sol._multi = h5["values"], multi
    if _BRANCHES[0] in h5:
        sol._set_branches(tuple(h5[name][()] for name in _BRANCHES))
    sol._sample(number_of_samples)
    return sol


class StoredSolution(Solution):
    """A :class:`~dolfinode.Solution` whose elements stay in an HDF5 file until needed (see
    :func:`load_solution`): the element times are read at the first evaluation, the nodal
    values only where an evaluation needs them."""

    @property
    def multi(self):
        return self._multi

    @cached_property
    def _times(self):
        """The element times (and, multi-adaptive, the file row of each element grouped by
        component, and the component pointer)."""
        h5 = self._h5
        if not self._multi:
            t_start, k = h5["t_start"][()], h5["k"][()]
            return {"t_start": t_start, "k": k, "_t_end": None, "_rows": None,
                    "_component_ptr": None}
        comp = h5["comp"][()]
        rows = np.lexsort((h5["t_start"][()], comp))  # file row of each element, grouped
        ptr = np.searchsorted(comp[rows], np.arange(self.ode.N + 1))
        del comp
        t_start, t_end = h5["t_start"][()][rows], h5["t_end"][()][rows]
        return {"t_start": t_start, "k": t_end - t_start, "_t_end": t_end, "_rows": rows,
                "_component_ptr": ptr}

    t_start = property(lambda self: self._times["t_start"])
    k = property(lambda self: self._times["k"])
    _t_end = property(lambda self: self._times["_t_end"])
    _rows = property(lambda self: self._times["_rows"])
    _component_ptr = property(lambda self: self._times["_component_ptr"])

    @property
    def values(self):
        """All nodal values, read from the file once."""
        if "_all_values" not in self.__dict__:
            stored = self._stored[()]
            self.__dict__["_all_values"] = stored[self._rows] if self.multi else stored
        return self.__dict__["_all_values"]

    def _evaluate(self, times, dense=True):
        """U at ``times`` from the elements around them, read from the file."""
        if "_all_values" in self.__dict__:
            return super()._evaluate(times, dense)
        out = np.empty((times.size, self.ode.N)).T
        nodes, bary = self.method.nodes, self.method.barycentric_weights
        if not self.multi:
            needed = self._elements_at(times)
            # (with the elements before them: dG(q)'s dense value reads the previous end)
            needed = np.union1d(needed, needed[needed > 0] - 1)
            h5 = self._h5
            t_start = h5["t_start"][needed]
            values = self._stored[needed]
            on_branches(self._branches, times, out, self._rhs if dense else None,
                        lambda at, rhs, part: evaluate_mono(
                            self.method, t_start, t_start + h5["k"][needed], values,
                            [self.ode.t0], [self.ode.u0], at, part, rhs))
            return out
        ptr = self._component_ptr
        needed = self._with_previous(self._holding([times] * self.ode.N))
        compiled = self._rhs if dense else None
        if compiled is not None:
            # (the dense value reads f_i at its elements' nodes and tau*, the others there
            # at their collocation polynomials, which read their neighbours alike)
            read = self._with_previous(self._read_by(needed, compiled))
            needed = np.union1d(np.union1d(needed, read), self._read_by(read, compiled))
        rows = self._rows[needed]
        order = np.argsort(rows)  # h5py reads rows in increasing order
        values = np.empty((needed.size, *self._stored.shape[1:]))
        values[order] = self._stored[rows[order]]
        counts = np.searchsorted(needed, ptr)
        _evaluate_components(counts, self.t_start[needed], self._t_end[needed], values, nodes,
                             bary, dense_rule(self.method), self.ode.t0, self.ode.u0, times,
                             out)
        if compiled is not None:
            none = np.empty(0)
            self._correct(counts, self.t_start[needed], self._t_end[needed], values, none,
                          none, np.empty((0, values.shape[1], self.ode.N)), times, out)
        return out

    def _end_values(self):
        return self._stored[-1, -1]

    def _elements_at(self, times):
        """The rows of the elements of a shared partition that ``times`` fall in (the first
        whose end t_start + k is >= t, as a history in memory finds them), increasing.

        The element times are read in blocks of a dataset chunk (131072 elements) around
        the times, found from the first time of every block: a file holds histories too
        long for memory, whose times alone (16 bytes per element) may not fit either."""
        if "_times" in self.__dict__:  # (read whole already)
            t_end = self.t_start + self.k
            return np.unique(np.minimum(np.searchsorted(t_end, times), len(t_end) - 1))
        t_start, k = self._h5["t_start"], self._h5["k"]
        n, block = len(t_start), t_start.chunks[0]
        if "_firsts" not in self.__dict__:
            self._firsts = t_start[::block]
        # the block of the last element starting before t; its element ending at or after
        # t may be the next block's first (t_start + k rounds below the next start)
        of_time = np.maximum(np.searchsorted(self._firsts, times) - 1, 0)
        rows = []
        for j in np.unique(of_time):
            a, b = j * block, min((j + 1) * block + 1, n)
            ends = t_start[a:b] + k[a:b]
            rows.append(a + np.minimum(np.searchsorted(ends, times[of_time == j]), b - a - 1))
        return np.unique(np.concatenate(rows))

    def _holding(self, times):
        """The elements holding times[i] (the first ending at or after each) per component i."""
        ptr = self._component_ptr
        return np.unique(np.concatenate([
            ptr[i] + np.minimum(np.searchsorted(self._t_end[ptr[i]:ptr[i + 1]], times[i]),
                                ptr[i + 1] - ptr[i] - 1) for i in range(self.ode.N)]))

    def _with_previous(self, elements):
        """``elements`` with each one's previous element of its component (mdG(q)'s dense
        value reads its end)."""
        return np.union1d(elements, elements[~np.isin(elements, self._component_ptr)] - 1)

    def _read_by(self, elements, compiled):
        """The elements of the components that f_i reads at the nodes of component i's
        ``elements`` and at the defect check's point (what :func:`_correct_multi` reads)."""
        ptr = self._component_ptr
        star = _defect_check(self.method.family, self.method.q)[0]
        fractions = np.append(self.method.nodes, star)
        owner = np.searchsorted(ptr, elements, side="right") - 1
        a, b = self.t_start[elements], self._t_end[elements]
        points = (a[:, None] + (b - a)[:, None] * fractions).ravel()
        owners = np.repeat(owner, fractions.size)
        read = [[] for _ in range(self.ode.N)]
        for i in np.unique(owner):
            mine = points[owners == i]
            for d in compiled.indices[compiled.indptr[i]:compiled.indptr[i + 1]]:
                read[d].append(mine)
        return self._holding([np.concatenate(r) if r else np.empty(0) for r in read])

    def close(self):
        """Close the file (a later evaluation that needs it raises)."""
        self._h5.close()

    def __getstate__(self):
        raise TypeError(f"a solution read lazily from {self.path} does not pickle: pickle "
                        "the file's path and load_solution it again")
