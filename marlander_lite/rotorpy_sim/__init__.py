"""RotorPy's Crazyflie as a third simulator: one the project did not write (see :mod:`.simulator`)."""
