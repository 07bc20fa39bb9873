"""The master's exchange strategies: one registry (docs/cosim-strategies.md, docs/design.md §4.4).

Every way the master exchanges the coupling forces is one :class:`Strategy` of :data:`STRATEGIES`:
its name, how a run selects it, its checks (which other strategies and holds it runs with, what the
FMU must offer), its step (the compiled loop's flags it sets, or the master class that runs it) and
its info (the keys it adds to ``result.info``). The API (:func:`fmu_sync.master.cosimulate_network`),
the scenes' schema, the SSP runner and the docs' table (:func:`table`) read it; nothing else keeps a
list of methods or a compatibility rule.

Two kinds: an **order** (``method=``: who gets which states' forces, one per run) and a **mode**
(``exchange="implicit"``, ``tol=``, ``event_aware=True``: how a step is taken, any that agree).
:func:`select` turns a run's arguments into its strategies and applies their checks before
anything runs; :func:`check_fmu` applies the FMU's (its FMI version, state access).

Adding a strategy: one entry here (its checks beside it) and its tests; a new compiled step also
one branch of the kernel (:mod:`fmu_sync.cosim_loop`) behind a new flag.

This module imports no numba (the scenes' schema reads it).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from .core.exchange import HOLDS, check_exchange_name
from .hold import check_hold_name

__all__ = ["Strategy", "STRATEGIES", "ORDERS", "MODES", "METHODS", "FMI2_METHODS", "NOT_DELAYED", "DELAYED",
           "DELAYED_ZERO", "Selection", "select", "check_fmu", "table", "flags_of", "master_of"]

#: the compiled loop's ``flags[DELAY]`` codes of the delayed orders (docs/ssp.md): step k held at the
#: forces of x_{k-1} (step 0 at x_0's); DELAYED_ZERO also starts every connection at 0 (steps 0, 1 unforced)
NOT_DELAYED, DELAYED, DELAYED_ZERO = range(3)


@dataclass(frozen=True)
class Selection:
    """What a run asks for: the master's arguments that choose and combine strategies."""
    method: str = "jacobi"
    exchange: str = "explicit"
    tol: float | None = None
    event_aware: bool = False
    hold: str = "zoh"


@dataclass(frozen=True)
class Strategy:
    """One way of exchanging. ``kind``: "order" (``method=name``) or "mode"; ``selected_by``: the
    argument that selects it (as its errors name it); ``fmi``: the FMI version of the FMUs it drives;
    ``rollback``: it sets the FMUs back to a saved state (canGetAndSetFMUstate); ``holds``: the holds
    it runs with; ``check``: its rules against the rest of the run (ValueError); ``flags``: the compiled
    loop's flags it sets (:data:`fmu_sync.cosim_loop.FLAG_NAMES`); ``master``: the master class that
    runs it ("module:Class", None: :class:`fmu_sync.master.NetworkMaster`); ``info``: the keys it adds."""
    name: str
    kind: str
    selected_by: str
    summary: str
    fmi: str = "2.0"
    rollback: bool = False
    holds: tuple = HOLDS
    check: Callable[[Selection], None] | None = None
    flags: dict = field(default_factory=dict)
    master: str | None = None
    info: tuple = ()
    doc: str = "docs/cosimulation.md"


# ------------------------------------------------------------------ the rules, each beside its entry
def _no_retake(name: str, sel: Selection, why: str) -> None:
    if sel.event_aware:
        raise ValueError(f"{name} and event_aware=True exclude each other (got {name}={getattr(sel, name)!r}, "
                         f"event_aware=True): {why}")


def _check_implicit(sel: Selection) -> None:
    if sel.method != "jacobi" or sel.event_aware:
        raise ValueError(f"exchange='implicit' iterates every step to its end states, so it takes "
                         f"method='jacobi' (its predictor) and no event_aware retake; got method={sel.method!r}, "
                         f"event_aware={sel.event_aware!r}")


def _check_tol(sel: Selection) -> None:
    _no_retake("tol", sel, "with tol a step in which an impact counter moves is retaken shorter by the error "
                           "control itself")
    if sel.method not in ("jacobi", "gauss-seidel"):
        raise ValueError(f"tol needs method 'jacobi' or 'gauss-seidel', got {sel.method!r}")


def _check_delayed(who: str) -> Callable[[Selection], None]:
    def check(sel: Selection) -> None:
        if sel.event_aware or sel.hold != "zoh":
            raise ValueError(f"method {sel.method!r} ({who}'s exchange order) runs with hold='zoh' and without "
                             f"event_aware, got hold={sel.hold!r}, event_aware={sel.event_aware!r}")
    return check


def _check_early_return(sel: Selection) -> None:
    if sel.event_aware or sel.hold != "zoh" or sel.exchange != "explicit" or sel.tol is not None:
        raise ValueError(f"method 'early-return' exchanges at every impact instant the FMUs return at, with "
                         f"hold='zoh', the explicit exchange, no tol and no event_aware retake; got "
                         f"hold={sel.hold!r}, exchange={sel.exchange!r}, tol={sel.tol!r}, "
                         f"event_aware={sel.event_aware!r}")


STRATEGIES: dict[str, Strategy] = {s.name: s for s in (
    Strategy("jacobi", "order", "method='jacobi'",
             "every instance's input from the states at the step's start"),
    Strategy("gauss-seidel", "order", "method='gauss-seidel'",
             "instances stepped in index order, each input from the newest states of the others",
             flags={"gauss_seidel": 1}),
    Strategy("delayed", "order", "method='delayed'",
             "libcosim's order: step k held at the forces of the states one step older (x_{k-1})",
             holds=("zoh",), check=_check_delayed("libcosim"), flags={"delay": DELAYED}, doc="docs/ssp.md"),
    Strategy("delayed-zero", "order", "method='delayed-zero'",
             "fmpy's simulate_ssp order: as delayed, every connection starting at 0",
             holds=("zoh",), check=_check_delayed("fmpy.ssp.simulate_ssp"), flags={"delay": DELAYED_ZERO},
             doc="docs/ssp.md"),
    Strategy("early-return", "order", "method='early-return'",
             "FMI 3.0: each step stops at the first impact (early return), the forces exchanged there",
             fmi="3.0", holds=("zoh",), check=_check_early_return, master="fmu_sync.early_return:EarlyReturnMaster",
             info=("early_stops", "stop_times"), doc="docs/fmi3.md"),
    Strategy("tol", "mode", "tol",
             "the communication step chosen by an error controller; a step over its share rolled back, retaken "
             "shorter", rollback=True, check=_check_tol, flags={"tol": 1},
             master="fmu_sync.master:AdaptiveMaster",
             info=("tol", "steps", "rejected", "step_lengths", "H_first", "step_unit", "error_estimate",
                   "floor_steps", "error_norm", "floor_error", "tol_met", "tol_not_met"),
             doc="docs/design.md §4.4.1"),
    Strategy("implicit", "mode", "exchange='implicit'",
             "each step iterated with FMU-state rollback until the forces agree with its end states",
             rollback=True, check=_check_implicit, flags={"implicit": 1},
             info=("iterations", "residuals", "exchange_tol", "off_branch")),
    Strategy("event-aware", "mode", "event_aware=True",
             "a step in which an impact counter moves is rolled back and retaken in pieces of H_min",
             rollback=True, flags={"event_aware": 1}, info=("H_min", "retaken_steps")),
)}

#: the orders (``method=``), and the ones that drive the FMI 2.0 FMU of ``fmu-sync export`` (scenes)
METHODS = tuple(n for n, s in STRATEGIES.items() if s.kind == "order")
FMI2_METHODS = tuple(n for n in METHODS if STRATEGIES[n].fmi == "2.0")
ORDERS = {n: STRATEGIES[n] for n in METHODS}
MODES = {n: s for n, s in STRATEGIES.items() if s.kind == "mode"}


def select(method: str = "jacobi", exchange: str = "explicit", tol=None, event_aware: bool = False,
           hold: str = "zoh") -> tuple[Strategy, ...]:
    """The strategies of a run (its order first, then its modes in the order tol, implicit,
    event-aware), every one's checks applied: ValueError naming the argument, its value and what is
    allowed, before anything runs."""
    orders = [n for n, s in STRATEGIES.items() if s.kind == "order"]   # read here: an entry added is selectable
    if method not in orders:
        raise ValueError(f"method must be {', '.join(repr(m) for m in orders[:-1])} or {orders[-1]!r}, "
                         f"got {method!r}")
    check_exchange_name(exchange)
    check_hold_name(hold)
    sel = Selection(method, exchange, tol, bool(event_aware), hold)
    chosen = (STRATEGIES[method],) + tuple(STRATEGIES[name] for on, name in (
        (tol is not None, "tol"), (exchange == "implicit", "implicit"), (bool(event_aware), "event-aware")) if on)
    for s in chosen:
        if s.check is not None:
            s.check(sel)
        if hold not in s.holds:
            raise ValueError(f"{s.selected_by} runs with hold={' or '.join(repr(h) for h in s.holds)}, got {hold!r}")
    return chosen


def check_fmu(chosen, md, fmu: str) -> None:
    """The FMU's side of the chosen strategies, before any instance exists: its FMI version (and, for
    FMI 3.0, early return), and the state access of every strategy that sets FMU states back (the
    first one's name in the error; the binary's functions are checked when it is loaded)."""
    want = {s.fmi for s in chosen}
    fmi = "3.0" if "3.0" in want else "2.0"
    cs = md.coSimulation
    if fmi == "3.0" and (md.fmiVersion != "3.0" or cs is None or not cs.mightReturnEarlyFromDoStep):
        raise ValueError(f"the early-return exchange needs an FMI 3.0 co-simulation FMU that may return early "
                         f"(mightReturnEarlyFromDoStep = true); {fmu} is FMI {md.fmiVersion}"
                         + ("" if md.fmiVersion != "3.0" else " without early return")
                         + ": export it with fmu-sync export --fmi-version 3, or use cosimulate with "
                           "event_aware=True on the FMI 2.0 FMU")
    if fmi == "2.0" and md.fmiVersion != "2.0":
        raise ValueError(f"{fmu} is an FMI {md.fmiVersion} FMU; cosimulate and cosimulate_network drive FMI 2.0 "
                         f"FMUs (export with --fmi-version 2) with method {', '.join(repr(m) for m in FMI2_METHODS)}; "
                         f"an FMI 3.0 FMU is driven by method='early-return' "
                         f"(fmu_sync.early_return.cosimulate_early_return: exchange at every impact instant)")
    back = [s for s in chosen if s.rollback]
    if back and not (cs is not None and cs.canGetAndSetFMUstate):
        who = back[0].selected_by
        raise ValueError(f"{who} sets the FMUs back to a saved state with fmi2GetFMUstate/fmi2SetFMUstate; "
                         f"{fmu} declares canGetAndSetFMUstate = false: run it without {who} (the explicit "
                         f"exchange at a fixed H)")


def flags_of(chosen) -> dict:
    """The compiled loop's flags the chosen strategies set, by name."""
    out: dict = {}
    for s in chosen:
        out.update(s.flags)
    return out


def master_of(chosen):
    """The master class that runs the chosen strategies (the last one naming one; NetworkMaster if none)."""
    import importlib
    path = next((s.master for s in reversed(chosen) if s.master), "fmu_sync.master:NetworkMaster")
    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


def table() -> str:
    """The registry as the markdown table of docs/cosim-strategies.md (a test keeps them equal)."""
    rows = ["| strategy | kind | selected by | FMI | holds | rolls back | info keys | what it does |",
            "|---|---|---|---|---|---|---|---|"]
    for s in STRATEGIES.values():
        rows.append(f"| `{s.name}` | {s.kind} | `{s.selected_by}` | {s.fmi} | {', '.join(s.holds)} | "
                    f"{'yes' if s.rollback else 'no'} | {', '.join(f'`{k}`' for k in s.info) or '-'} | "
                    f"{s.summary} ({s.doc}) |")
    return "\n".join(rows) + "\n"
