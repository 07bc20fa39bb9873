"""Built-in sweep scenes (``fmu-sync sweep --list``): a scene, a grid or sample, the map's axes."""
