"""``fmu-sync export MODEL -o PATH.fmu [--set name=value ...]`` (:mod:`fmu_sync.export`)."""
from __future__ import annotations

import argparse
import sys

from .. import native
from .archive import FMI_VERSIONS, export_coupling, export_fmu
from .carried import COUPLING, MODELS, model_slave, resolve


def _parse_set(items: list[str]) -> dict:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--set expects name=value, got {item!r}")
        out[name.strip()] = value.strip()
    return out


def main_export(argv=None) -> int:
    """``fmu-sync export MODEL -o PATH.fmu [--set name=value ...]``; returns the exit code."""
    parser = argparse.ArgumentParser(
        prog="fmu-sync export",
        description="Export an FMI 2.0 (or FMI 3.0: --fmi-version 3) co-simulation FMU of an fmu-sync model, "
                    "or the coupling FMU of a pair or network (the importing machine needs Python with numpy; "
                    "the stepper is compiled here into the FMU's binary; see docs/fmu.md).")
    parser.add_argument("model", help=f"model to export: {', '.join(sorted([*MODELS, COUPLING]))}, a built-in "
                                      f"declaration (pendulum, duffing) or a user's model file "
                                      f"path/to/model.py:name (docs/user-model.md)")
    parser.add_argument("-o", "--output", default=None,
                        help="FMU file to write (default: <ModelIdentifier>.fmu in the current folder)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="NAME=VALUE",
                        help="start value of a parameter or input, e.g. --set e=0.8 "
                             "--set solver.scheme=theta --set 'M[1,2]=0.3' (repeatable)")
    parser.add_argument("--fmi-version", type=int, choices=FMI_VERSIONS, default=2,
                        help="FMI version of the FMU: 2 (default) or 3 (FMI 3.0: event mode, early return "
                             "at impacts, arrays; see docs/fmi3.md; not for the coupling FMU)")
    parser.add_argument("--nodes", type=int, default=None,
                        help="coupling only: number of coupled systems N (default 2, the pair)")
    parser.add_argument("--graph", default="ring",
                        help="coupling only, with --nodes: ring, path, star or all-to-all (default ring)")
    parser.add_argument("--dof", type=int, default=1,
                        help="coupling only: degrees of freedom n of each system (default 1)")
    parser.add_argument("--list", action="store_true", help="list the model's variables and exit")
    args = parser.parse_args(argv)
    try:
        if args.model != COUPLING and (args.nodes is not None or args.dof != 1):
            raise ValueError(f"--nodes and --dof are options of the coupling FMU, not of {args.model}")
        if args.model == COUPLING:
            from ..core.network import graph
            from ..fmus.coupling import CouplingSlave, CouplingSpec
            A = graph(args.graph, 2 if args.nodes is None else args.nodes)
            cls = CouplingSlave(CouplingSpec.from_weights(A, args.dof))
        else:
            cls = model_slave(resolve(args.model)[0])
        if args.list:
            for v in cls.declare():
                unit = f" [{v.unit}]" if v.unit else ""
                start = f" = {v.start}" if v.start is not None else ""
                print(f"{v.name:<14} {v.causality:<9} {v.type:<11}{unit}{start}  {v.description}")
            return 0
        if args.model == COUPLING:
            if args.fmi_version != 2:
                raise ValueError("the coupling FMU is exported for FMI 2.0 only (--fmi-version 2)")
            path = export_coupling(args.output, A, args.dof, _parse_set(args.sets))
        else:
            path = export_fmu(args.model, args.output, _parse_set(args.sets), fmi_version=args.fmi_version)
    except (ValueError, native.NativeCodeError) as exc:
        print(f"fmu-sync export: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0
