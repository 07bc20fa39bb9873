"""The coupling FMU at extreme finite parameters and inputs (issue 35 item 5), through fmpy:
parameters that make its forces non-finite or beyond what the systems accept as their input
(|tau| <= contract.INPUT_BOUND) are refused at fmi2ExitInitializationMode naming them; during a
run its outputs never exceed that bound (fmi2Error with the reason instead); no numpy warning
reaches the host's stderr; the in-wall warning reads "0 m", never "-0 m".

The FMU is loaded in a child process (``python tests/test_coupling_bounds.py SCENARIO ARGS OUT``)
whose stderr the test reads.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path


# =============================================================== child side
def _host(fmu, name):
    from fmu_sync.fmi_bridge import FMUHost
    h = FMUHost(fmu, name)
    h.enter_initialization(0.0)
    return h


def _log(h):
    out = [m for s, _, m in h.messages if s >= 1]
    h.messages.clear()
    return out


def scenario_refusals(a):
    """exitInitializationMode with each parameter set; then getReal of parameters and outputs."""
    out = {}
    for key, params in a["cases"].items():
        h = _host(a["fmu"], key)
        status = h.exit_initialization(params)
        log = _log(h)
        got = {n: h.call("getReal", [h.vr(n)]) for n in ("Kp", "Kd", "f0[1]", "F[1]", "M", "tau[1]")}
        out[key] = {"status": status, "log": log, "get": {n: [s, r[0] if r else None] for n, (s, r) in got.items()},
                    "after": _log(h)}
        h.close()
    return out


def scenario_forces(a):
    """Random parameter sets and inputs: the status and the outputs of each getReal and doStep."""
    rows = []
    for k, case in enumerate(a["cases"]):
        h = _host(a["fmu"], f"r{k}")
        init = h.exit_initialization(case["params"])
        row = {"init": init, "init_log": _log(h), "inputs": []}
        t = 0.0
        if init <= 1:
            taus = [h.vr("tau[1]"), h.vr("tau[2]")]
            for x in case["inputs"]:
                h.set(dict(zip(["q[1]", "q[2]", "u[1]", "u[2]"], x)))
                st, tau = h.call("getReal", taus)
                step = h.do_step(t, 0.01)
                if step <= 1:
                    t += 0.01
                row["inputs"].append({"get": st, "tau": tau, "step": step, "log": _log(h)})
        rows.append(row)
        h.close()
    return rows


def scenario_wall(a):
    """A start state inside the wall (no step taken yet: the allowed penetration is 0); the logged warning."""
    h = _host(a["fmu"], "wall")
    h.exit_initialization({})
    h.set({"q[1]": -0.5, "q[2]": 0.5})
    st, tau = h.call("getReal", [h.vr("tau[1]")])
    return {"status": st, "log": _log(h)}


def _child_main(argv):
    name, args_path, out_path = argv
    Path(out_path).write_text(json.dumps(globals()[f"scenario_{name}"](json.loads(Path(args_path).read_text()))))


# =============================================================== parent side
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from fmu_sync.core import ImpactOscillator  # noqa: E402
from fmu_sync.core.coupling import coupling_forces  # noqa: E402
from fmu_sync.fmus.contract import INPUT_BOUND  # noqa: E402

ERROR = 3


def _run(name: str, args: dict, tmp: Path):
    """The scenario in a child; (its result, its stderr)."""
    (tmp / f"{name}.json").write_text(json.dumps(args))
    p = subprocess.run([sys.executable, __file__, name, str(tmp / f"{name}.json"), str(tmp / f"{name}.out")],
                       capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads((tmp / f"{name}.out").read_text()), p.stderr


@pytest.fixture(scope="module")
def fmu(shared_fmu):
    return str(shared_fmu("coupling"))


REFUSED = {   # parameters -> the names the refusal must carry
    "Kp-1e308": ({"Kp": 1e308}, ["Kp", "overflows"]),
    "Kd-1e308": ({"Kd": 1e308}, ["Kd", "overflows"]),
    "Kp-1e12": ({"Kp": 1e12}, ["Kp = 1e+12", "beyond |tau| <= 1e+12"]),
    "weight-1e300": ({"a[1,2]": 1e300}, ["a[1,2] = 1e+300", "beyond |tau| <= 1e+12"]),
    "M-1e308": ({"M": 1e308}, ["M, w, g0, e", "overflows"]),
    "Q-1e308": ({"Q": 1e308}, ["metric Q", "overflows"]),
    "f0+F-overflow": ({"law[1]": 3, "f0[1]": 1e308, "F[1]": 1e308}, ["k, c, f0, F = 1, 0, 1e+308, 1e+308",
                                                                        "reaches inf"]),
    "f0+F-beyond": ({"law[1]": 3, "f0[1]": 6e11, "F[1]": 6e11}, ["k, c, f0, F = 1, 0, 6e+11, 6e+11",
                                                                 "beyond |tau| <= 1e+12"]),
}


@pytest.fixture(scope="module")
def refusals(fmu, tmp_path_factory):
    cases = {k: v[0] for k, v in REFUSED.items()}
    cases["accepted"] = {"Kp": 1e5, "Kd": 1e3, "law[1]": 3, "f0[1]": 1e3, "F[1]": 1e3}
    return _run("refusals", {"fmu": fmu, "cases": cases}, tmp_path_factory.mktemp("refusals"))


@pytest.mark.parametrize("key", list(REFUSED))
def test_exit_initialization_refuses_forces_beyond_the_bound_naming_them(refusals, key):
    got = refusals[0][key]
    assert got["status"] == ERROR, got
    msg = got["log"][-1]
    assert msg.startswith("fmi2ExitInitializationMode: invalid configuration")
    for word in REFUSED[key][1]:
        assert word in msg, (word, msg)
    # the parameters stay readable after the refusal (the outputs are NaN, said with a warning)
    params = REFUSED[key][0]
    for name in ("Kp", "f0[1]", "F[1]"):
        status, value = got["get"][name]
        assert status == 0 and value == params.get(name, value), (name, got["get"])
    assert got["get"]["tau[1]"][0] <= 1 and np.isnan(got["get"]["tau[1]"][1])


def test_a_physical_parameter_set_is_accepted(refusals):
    got = refusals[0]["accepted"]
    status, tau = got["get"]["tau[1]"]
    assert got["status"] == 0 and status == 0 and abs(tau) <= INPUT_BOUND, got


def test_no_numpy_warning_reaches_the_hosts_stderr(refusals):
    stderr = refusals[1]
    assert "RuntimeWarning" not in stderr and "overflow encountered" not in stderr, stderr[-2000:]


IO = ImpactOscillator(m=1.0, k=1.0, c=0.0, e=0.9)
Q = 3.0


def _cases(rng, count: int = 40, inputs: int = 5):
    """Random gains, weights and laws (magnitudes over 15 decades) and random admissible inputs up to
    the input bound."""
    out = []
    for _ in range(count):
        params = {"Kp": float(10 ** rng.uniform(-3, 12.5)), "Kd": float(10 ** rng.uniform(-3, 12)),
                  "a[1,2]": float(10 ** rng.uniform(-3, 3)), "a[2,1]": float(10 ** rng.uniform(-3, 3)),
                  "law[1]": int(rng.integers(0, 2)), "Q": Q}
        xs = []
        for _ in range(inputs):
            mag = 10 ** rng.uniform(-3, 10, 4)
            x = mag * np.array([1.0, 1.0, rng.choice([-1, 1]), rng.choice([-1, 1])])   # q >= 0: outside the wall
            xs.append([float(v) for v in x])
        out.append({"params": params, "inputs": xs})
    return out


@pytest.fixture(scope="module")
def forces(fmu, tmp_path_factory):
    cases = _cases(np.random.default_rng(35))
    got, stderr = _run("forces", {"fmu": fmu, "cases": cases}, tmp_path_factory.mktemp("forces"))
    return cases, got, stderr


def test_outputs_never_exceed_the_bound_and_equal_the_core_within_it(forces):
    """Property over random parameters and inputs: a parameter set is accepted iff its unit-difference
    force sum_j a_ij (2 Kp + 2 Kd) is within the bound; then each getReal and doStep is fmi2OK with the
    core's coupling_forces when those are finite and within |tau| <= INPUT_BOUND, and fmi2Error naming
    the bound when not: no output beyond it is ever returned."""
    cases, rows, stderr = forces
    seen = {"refused": 0, "within": 0, "beyond": 0}
    for case, row in zip(cases, rows):
        p = case["params"]
        unit = max(p["a[1,2]"], p["a[2,1]"]) * (2 * p["Kp"] + 2 * p["Kd"])
        if unit > INPUT_BOUND:
            assert row["init"] == ERROR and "beyond |tau| <= 1e+12" in row["init_log"][-1], row
            seen["refused"] += 1
            continue
        assert row["init"] == 0, row
        law = ("switching", "euclidean")[p["law[1]"]]
        for x, got in zip(case["inputs"], row["inputs"]):
            with np.errstate(all="ignore"):
                t1, t2 = coupling_forces(IO, (x[0], x[2]), (x[1], x[3]), law, p["Kp"], p["Kd"], Q=Q)
                ref = np.array([p["a[1,2]"] * t1[0], p["a[2,1]"] * t2[0]])
            if np.all(np.abs(ref) <= INPUT_BOUND):
                assert got["get"] == 0 and got["step"] == 0, got
                assert np.allclose(got["tau"], ref, rtol=1e-12, atol=0.0), (got["tau"], ref)
                seen["within"] += 1
            else:
                assert got["get"] == ERROR and got["step"] == ERROR and got["tau"] is None, got
                assert any("exceeds |tau| <= 1e+12" in m for m in got["log"]), got["log"]
                seen["beyond"] += 1
    print(f"\nrandom cases: {seen}")
    assert min(seen.values()) >= 5, seen          # every outcome drawn
    assert "RuntimeWarning" not in stderr, stderr[-2000:]


def test_the_in_wall_warning_reads_0_m_not_minus_0(fmu, tmp_path):
    got, _ = _run("wall", {"fmu": fmu}, tmp_path)
    assert got["status"] <= 1 and len(got["log"]) == 1     # fmpy returns a warning's values (logged)
    msg = got["log"][-1]
    assert "allowed Moreau penetration 0 m" in msg and "-0 m" not in msg, msg


if __name__ == "__main__":
    _child_main(sys.argv[1:])
