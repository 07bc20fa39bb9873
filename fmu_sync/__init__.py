"""fmu-sync: controlled synchronization of impacting mechanical systems."""
