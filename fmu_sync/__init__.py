"""fmu-sync: controlled synchronization of impacting mechanical systems."""


def __getattr__(name):
    # fmu_sync.sweep(...) without importing xarray on `import fmu_sync`
    if name == "sweep":
        from .sweeps import sweep
        return sweep
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
