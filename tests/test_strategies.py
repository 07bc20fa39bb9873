"""The strategy registry (issue 43 item 1, fmu_sync.strategies): every way of exchanging is one entry
that the API, the scenes, the SSP runner and the docs read; its compatibility rules are the entries'
(checked here against the rules 0.7.0 kept in four places, written out independently); adding a
strategy is one entry."""
from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from fmu_sync import strategies as reg
from fmu_sync.master import AdaptiveMaster, NetworkMaster, cosimulate

ROOT = Path(__file__).resolve().parents[1]
X1, X2 = (1.0, 0.0), (0.2, 0.5)
LAW = dict(coupling="switching", Kp=1.0, Kd=0.5)
FORCED = dict(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)

METHODS = ("jacobi", "gauss-seidel", "delayed", "delayed-zero", "early-return")
COMBOS = list(itertools.product(METHODS + ("newton",), ("explicit", "implicit", "newton"), (None, 1e-3),
                                (False, True), ("zoh", "foh", "soh")))


def allowed_0_7(method, exchange, tol, event_aware, hold):
    """The rules of 0.7.0 (hold.py, master.py, ssp_master.py, early_return.py), written out."""
    if method not in METHODS or exchange not in ("explicit", "implicit") or hold not in ("zoh", "foh"):
        return False
    if exchange == "implicit" and (method != "jacobi" or event_aware):                   # hold.check_implicit
        return False
    if tol is not None and (event_aware or method not in ("jacobi", "gauss-seidel")):   # AdaptiveMaster
        return False
    if method in ("delayed", "delayed-zero") and (event_aware or hold != "zoh"):        # SspMaster
        return False
    if method == "early-return" and (event_aware or hold != "zoh" or exchange != "explicit" or tol is not None):
        return False                     # EarlyReturnMaster: Jacobi, zoh, no retake, no tol, explicit
    return True


def test_the_registry_holds_every_way_of_exchanging_of_the_issue():
    assert set(reg.STRATEGIES) == {"jacobi", "gauss-seidel", "delayed", "delayed-zero", "early-return", "tol",
                                   "implicit", "event-aware"}
    assert reg.METHODS == METHODS and reg.FMI2_METHODS == METHODS[:-1]
    for s in reg.STRATEGIES.values():
        assert s.kind in ("order", "mode") and s.summary and set(s.holds) <= {"zoh", "foh"}
        assert set(s.flags) <= set(__import__("fmu_sync.cosim_loop").cosim_loop.FLAG_NAMES)


@pytest.mark.parametrize("method, exchange, tol, event_aware, hold", COMBOS)
def test_select_accepts_exactly_what_0_7_accepted(method, exchange, tol, event_aware, hold):
    if not allowed_0_7(method, exchange, tol, event_aware, hold):
        with pytest.raises(ValueError) as err:
            reg.select(method, exchange, tol, event_aware, hold)
        assert "got" in str(err.value)          # names the offending value
        return
    chosen = reg.select(method, exchange, tol, event_aware, hold)
    names = [s.name for s in chosen]
    assert names[0] == method
    assert ("tol" in names) == (tol is not None) and ("implicit" in names) == (exchange == "implicit")
    assert ("event-aware" in names) == event_aware
    flags = reg.flags_of(chosen)   # the loop's flags as 0.7.0's loop_arguments (and AdaptiveMaster) set them
    assert flags.get("gauss_seidel", 0) == (method == "gauss-seidel")
    assert flags.get("delay", 0) == {"delayed": reg.DELAYED, "delayed-zero": reg.DELAYED_ZERO}.get(method, 0)
    assert flags.get("implicit", 0) == (exchange == "implicit")
    assert flags.get("event_aware", 0) == event_aware and flags.get("tol", 0) == (tol is not None)
    want = AdaptiveMaster if tol is not None else NetworkMaster
    if method == "early-return":
        from fmu_sync.early_return import EarlyReturnMaster as want
    assert reg.master_of(chosen) is want


def test_the_scenes_and_the_ssp_settings_read_the_registry():
    from fmu_sync.scenes import schema
    assert schema.METHODS == reg.FMI2_METHODS and schema.HOLDS == ("zoh", "foh")
    keys = (ROOT / "docs" / "scene-keys.md").read_text(encoding="utf-8")
    assert all(f'"{m}"' in keys for m in reg.FMI2_METHODS)


def test_the_docs_table_is_the_registry():
    page = (ROOT / "docs" / "cosim-strategies.md").read_text(encoding="utf-8")
    begin, end = "<!-- strategies table: begin (fmu_sync.strategies.table()) -->\n", "<!-- strategies table: end -->"
    assert page.count(begin) == 1 and page.count(end) == 1
    assert page.split(begin, 1)[1].split(end, 1)[0] == reg.table(), \
        "docs/cosim-strategies.md is stale: paste fmu_sync.strategies.table() between its markers"


@pytest.fixture(scope="module")
def fmu(shared_fmu):
    return shared_fmu("impact-oscillator", 2, dict(FORCED, **{"solver.dt": 1e-3}))


def test_each_entry_s_info_keys_are_in_its_runs_info_and_H_is_the_nominal_step(fmu):
    for kw in (dict(method="gauss-seidel"), dict(method="delayed"), dict(event_aware=True),
               dict(tol=1e-3), dict(exchange="implicit")):
        r = cosimulate(fmu, X1, X2, 0.3, 0.05, **LAW, **kw)
        chosen = reg.select(**kw)
        assert r.info["strategies"] == [s.name for s in chosen]
        for s in chosen:
            assert set(s.info) <= set(r.info), (s.name, set(s.info) - set(r.info))
        assert isinstance(r.info["H"], float) and r.info["H"] == 0.05, kw   # one schema in every mode
    assert np.isclose(np.sum(r.info["step_lengths"]) if "step_lengths" in r.info else 0.3, 0.3)


def test_the_api_runs_the_delayed_orders_as_the_ssp_master_did(fmu):
    """method='delayed' through cosimulate: the libcosim order (step k at the forces of x_{k-1}); its
    first step is held at the start states' forces, so its record's tau at row 1 is row 0's."""
    r = cosimulate(fmu, X1, X2, 0.3, 0.05, **LAW, method="delayed")
    j = cosimulate(fmu, X1, X2, 0.3, 0.05, **LAW)
    assert np.array_equal(r.tau1[1], j.tau1[1]) and not np.array_equal(r.q1[2:], j.q1[2:])
    assert np.array_equal(r.tau1[2], j.tau1[1])   # step 1 held at x_0's forces (Jacobi's step 0 force)


def test_adding_a_strategy_is_one_entry(fmu, monkeypatch):
    """A new order as one registry entry (here Jacobi under another name with its own check): the
    API selects it, applies its check and runs it; nothing else changes."""
    def check(sel):
        if sel.hold != "zoh":
            raise ValueError(f"method 'jacobi-zoh' holds its inputs, got hold={sel.hold!r}")
    entry = reg.Strategy("jacobi-zoh", "order", "method='jacobi-zoh'", "Jacobi, zoh only", check=check)
    monkeypatch.setitem(reg.STRATEGIES, entry.name, entry)
    r = cosimulate(fmu, X1, X2, 0.3, 0.05, **LAW, method="jacobi-zoh")
    j = cosimulate(fmu, X1, X2, 0.3, 0.05, **LAW)
    assert r.info["strategies"] == ["jacobi-zoh"] and np.array_equal(r.q1, j.q1)
    with pytest.raises(ValueError, match="holds its inputs, got hold='foh'"):
        cosimulate(fmu, X1, X2, 0.3, 0.05, **LAW, method="jacobi-zoh", hold="foh")
