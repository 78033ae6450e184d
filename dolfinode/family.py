"""``method="auto"``: the mono- or multi-adaptive variant of a method, chosen from pilot solves.

A multi-adaptive element costs several mono-adaptive component-steps (its own moments,
sweeps and partition), so mcG(q)/mdG(q) pay off only where the components' steps spread
widely; which variant is cheaper on a given problem is measured, not guessed. Both variants
solve growing pilot intervals [t0, t0 + H] (H grows GROWTH-fold from PILOT_START (T - t0)) until
H >= PILOT_END (T - t0), in a race: the variant that has spent less CPU time runs next (its
first pilot, which also builds the method's tables, not counted). A variant's cost over
[t0, T] is predicted by its marginal rate,

    rate = (c(H) - c(H / GROWTH)) / (H - H / GROWTH),

the CPU time c of its last two pilots differenced, so that the fixed cost per call cancels.
When both reach PILOT_END the smaller rate wins; a variant whose pilots, with its next one,
would cost more than ABANDON x the other's predicted time loses before. The winner solves [t0, T] from the start,
so the result is that method's own solve; the pilots cost a few percent of it.

Limitation: the choice is made once, from the first percent of [t0, T]. A problem whose fast
scale appears later (a chain whose stiff springs are excited slowly) keeps the variant that
was cheaper at its start.
"""
import copy
import re
import time

from dolfinode.compile import lower
from dolfinode.errors import SolverError

#: "auto" is "auto:cG(2)"; "auto:cG(q)" and "auto:dG(q)" race cG(q)/mcG(q), dG(q)/mdG(q).
_AUTO_PATTERN = re.compile(r"^\s*auto\s*(?::\s*((?:cG|dG)\(\s*\d+\s*\)))?\s*$", re.IGNORECASE)
DEFAULT_BASE = "cG(2)"
#: The first pilot interval and the one the faster variant reaches, as fractions of T - t0.
PILOT_START, PILOT_END = 1e-3, 1e-2
#: Growth of the pilot intervals: few pilots, since each costs a call's fixed time (with
#: doubling intervals a small solve paid for five pilots per variant).
GROWTH = 4
#: A variant whose pilots, with its next one, would cost more than ABANDON x the predicted time
#: of the other (that has reached PILOT_END) loses without them: the pilots stay a small part
#: of the solve.
ABANDON = 0.1
#: Parameters a pilot overrides: output, progress, modeling and events are the final solve's
#: business (sample times and a history file refer to [t0, T]).
_PILOT_PARAMETERS = {"number_of_samples": 2, "sample_times": None, "dense_output": True,
                     "progress": False, "automatic_modeling": False, "events": None}


def auto_base(method):
    """The base method name ("cG(q)" or "dG(q)") of an "auto" method name, else None."""
    if not isinstance(method, str):
        return None
    match = _AUTO_PATTERN.match(method)
    if match is None:
        return None
    base = match.group(1) or DEFAULT_BASE
    return base[0].lower() + base[1].upper() + base[2:].replace(" ", "")


def choose_family(solve, ode, base, parameters):
    """Race the mono- and multi-adaptive variants of ``base`` on pilot intervals of ``ode``.

    Parameters
    ----------
    solve : the driver, ``solve(ode, method, **parameters)``
    ode : ODE
    base : "cG(q)" or "dG(q)"
    parameters : the solve's parameters (the goal and automatic modeling apart)

    Returns
    -------
    method : str
        ``base`` or ``"m" + base``, whichever has the smaller rate.
    evidence : dict
        For ``sol.stats["family choice"]``: the chosen method, the CPU time of all pilots,
        and per variant its pilot horizons, CPU times, elements, the marginal rate (CPU s per
        unit time) and the predicted time over [t0, T]; for the multi-adaptive variant the
        efficiency index of its last pilot (mono elements / elements); a variant whose pilot
        failed has its error, one abandoned says so.
    """
    from dolfinode.timeslab import multi  # noqa: F401  (loaded now, not inside a pilot's time)

    lower(ode)  # compiled once, shared by the pilots (a copy would compile again)
    span = ode.T - ode.t0
    variants = {base: _Pilots(), "m" + base: _Pilots()}
    pilot_parameters = {**parameters, **_PILOT_PARAMETERS}
    while True:
        running = [name for name, p in variants.items() if p.error is None]
        if len(running) < 2:  # a variant that fails on a pilot is out (both: the solve says why)
            chosen = running[0] if running else base
            return chosen, _evidence(chosen, variants, span)
        done = [name for name in running if variants[name].covered(PILOT_END * span)]
        if len(done) == 2:
            best = min(done, key=lambda name: variants[name].rate())
            return best, _evidence(best, variants, span)
        for name, other in (running, running[::-1]):
            if other in done and variants[name].next_spent() > ABANDON * variants[other].rate() * span:
                variants[name].abandoned = True
                return other, _evidence(other, variants, span)
        # the race: of those still short of PILOT_END, the one that has spent less runs next
        name = min((name for name in running if name not in done),
                   key=lambda name: variants[name].spent())
        variants[name].run(solve, ode, name, pilot_parameters, PILOT_START * span)


class _Pilots:
    """The pilot solves of one variant over growing intervals [t0, t0 + H]."""

    def __init__(self):
        self.horizons, self.times, self.elements = [], [], []
        self.efficiency = None
        self.error = None
        self.abandoned = False

    def covered(self, horizon):
        """Whether two pilots ran and the last reached ``horizon``."""
        return len(self.horizons) >= 2 and self.horizons[-1] >= horizon

    def spent(self):
        """CPU time of the pilots but the first, which also builds the method's tables."""
        return sum(self.times[1:])

    def next_spent(self):
        """spent() after the next pilot, whose time is taken GROWTH x the last one's."""
        return self.spent() + GROWTH * self.times[-1] if self.times else 0.0

    def rate(self):
        """Marginal CPU time per unit time of [t0, T], from the last two pilots."""
        dt = self.times[-1] - self.times[-2]
        dh = self.horizons[-1] - self.horizons[-2]
        # timing noise may make the difference negative: then the mean rate bounds it
        return dt / dh if dt > 0 else self.times[-1] / self.horizons[-1]

    def run(self, solve, ode, method, parameters, start):
        horizon = GROWTH * self.horizons[-1] if self.horizons else start
        pilot = copy.copy(ode)
        pilot._compiled = ode._compiled
        pilot.T = min(ode.t0 + horizon, ode.T)
        clock = time.process_time()
        try:
            sol = solve(pilot, method, **parameters)
        except SolverError as error:
            self.error = str(error)
            return
        self.times.append(time.process_time() - clock)
        self.horizons.append(horizon)
        self.elements.append(sol.stats["elements"])
        self.efficiency = sol.stats.get("efficiency index")


def _evidence(chosen, variants, span):
    evidence = {"method": chosen,
                "pilot cpu time": sum(sum(p.times) for p in variants.values())}
    for name, p in variants.items():
        entry = {"pilot horizons": list(p.horizons), "pilot cpu times": list(p.times),
                 "pilot elements": list(p.elements)}
        if len(p.horizons) >= 2:
            entry["rate"] = p.rate()
            entry["predicted time"] = p.rate() * span
        if p.efficiency is not None:
            entry["efficiency index"] = p.efficiency
        if p.error is not None:
            entry["error"] = p.error
        if p.abandoned:
            entry["abandoned"] = (f"its pilots with the next would cost more than {ABANDON:g} x "
                                  f"the predicted time of {chosen}")
        evidence[name] = entry
    return evidence
