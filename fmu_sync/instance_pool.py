"""FMU instances kept between co-simulation runs in one process (a sweep worker's).

Instantiating an instance (fmpy loads the binary's functions, the FMU builds its
Python instance) costs more than a short run; a sweep runs hundreds of runs of one
FMU per worker. :func:`keep_instances` names an unpacked FMU folder whose runs keep
their instances: at its end a run resets each one (fmi2Reset; one that fails or had a
fatal error is freed instead) and the next run on that folder takes it up where a
fresh instance starts (fmi2SetupExperiment, initialisation, its own start values).
Bit for bit as fresh instances (tests/test_fmu_reset.py, tests/test_cosim_reuse.py).
The master (:class:`fmu_sync.master.NetworkMaster`) keeps FMI 2.0 instances only;
kept instances are freed at exit.
"""
from __future__ import annotations

import atexit

__all__ = ["keep_instances", "kept_key", "take", "give_back"]

_KEPT: dict = {}          # (folder, GUID, instance name) -> an idle, reset instance
_FOLDERS: set = set()


def keep_instances(unzipdir) -> None:
    """Runs in this process on the unpacked FMU folder ``unzipdir`` keep their instances."""
    if not _FOLDERS:
        atexit.register(_free_all)
    _FOLDERS.add(str(unzipdir))


def kept_key(unzipdir, guid: str, name: str):
    """The key of an instance of ``unzipdir`` (None: its runs do not keep instances)."""
    return (str(unzipdir), guid, name) if str(unzipdir) in _FOLDERS else None


def take(key):
    """The kept instance of ``key``, or None (then the caller instantiates one)."""
    return None if key is None else _KEPT.pop(key, None)


def give_back(key, instance) -> None:
    """At the end of a run: reset ``instance`` (a master's ``FmuInstance``) and keep it under
    ``key``, or free it (no key, one already kept, a fatal error or a failed fmi2Reset)."""
    if key is None or key in _KEPT or instance.dead or _reset(instance) > 1:
        instance.close()
        return
    _KEPT[key] = instance


def _reset(instance) -> int:
    """fmi2Reset's status (a master's instance raises for a status worse than Warning)."""
    from .fmi_bridge import SlaveError
    try:
        return instance.reset()
    except SlaveError as exc:
        return exc.status


def _free_all() -> None:
    for key in list(_KEPT):
        _KEPT.pop(key).close()
