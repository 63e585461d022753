"""PyFlyt's Crazyflie as a fourth simulator: a second one the project did not write (see :mod:`.simulator`)."""
