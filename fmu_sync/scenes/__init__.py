"""Built-in scenes (SPEC §6): one TOML file per scene, loaded by :mod:`fmu_sync.scene`.

Copy any of these files, edit it and run it with ``fmu-sync run my-scene.toml``.
The format is documented in :mod:`fmu_sync.scene` and in the comments of
``paper-example.toml``.
"""
from pathlib import Path

#: Folder holding the built-in ``*.toml`` scenes.
SCENE_DIR = Path(__file__).resolve().parent

__all__ = ["SCENE_DIR", "builtin_names"]


def builtin_names() -> list[str]:
    """Names (file stems) of the built-in scenes, sorted."""
    return sorted(p.stem for p in SCENE_DIR.glob("*.toml"))
