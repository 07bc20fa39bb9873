"""A coupled scene as an SSP 1.0 package, and our master running one (docs/ssp.md).

    write_ssp("forced-pair", "pair.ssp", variant="switching")
    fmu-sync ssp forced-pair --variant switching -o pair.ssp
    run_ssp("pair.ssp")            # fmu-sync run pair.ssp

The package (a zip archive) holds:

* ``SystemStructure.ssd``: one component per system (``system1`` .. ``systemN``,
  all instances of one oscillator FMU file), the coupling component
  (``coupling``, the coupling FMU of :mod:`fmu_sync.fmus.coupling`), the
  connections (each system's q, u to the coupling's ``q[i]``, ``u[i]``; the
  coupling's ``tau[i]`` to the system's ``tau``) and a DefaultExperiment with
  the scene's ``t_end`` and, as the Open Simulation Platform annotation that
  libcosim reads, its communication step H;
* ``resources/<model>.fmu`` and ``resources/coupling.fmu``;
* ``resources/<component>.ssv``: each component's parameter values (a system's
  parameters and start state, the coupling's weights, gains, metric Q and the
  impact geometry). With the law ``switching-compensated`` the coupling's copy of each
  system's force law (``k[i]`` .. ``phi[i]``) is bound from that system's own ``.ssv``
  through a parameter mapping ``resources/coupling-<system>.ssm`` (``k`` -> ``k[i]``, ..):
  one set of numbers for both, and :func:`run_ssp` refuses a package whose coupling
  holds another. Only Real values are bound: the enumerations (the solver
  scheme, the law of each edge) are the FMUs' start values, since libcosim
  cannot set FMI enumerations and fmpy's runner cannot read SSV enumeration names.

:func:`run_ssp` reads a package back (ours, or one edited by another tool that
keeps this structure) and runs it in :class:`fmu_sync.master.NetworkMaster`: the
coupling component's parameters become the master's graph, laws and gains
(:class:`fmu_sync.ssp_master.SspMaster`, which also runs libcosim's and fmpy's orders).
"""
from __future__ import annotations

from .common import (COUPLING_COMPONENT, NS, OMS, OMS_SOLVER, OSP, SSD, SsdError, SspError,  # noqa: F401
                     system_component)
from .reader import SspPackage, fmpy_parameter_set, read_ssp
from .runner import run_ssp, save_result
from .writer import write_ssp

__all__ = ["write_ssp", "read_ssp", "run_ssp", "save_result", "SspPackage", "fmpy_parameter_set", "SSD", "SspError", "SsdError",
           "COUPLING_COMPONENT", "system_component"]
