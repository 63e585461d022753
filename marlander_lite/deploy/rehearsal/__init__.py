"""The rehearsal: the lab loop of :mod:`marlander_lite.deploy` flown against a simulated lab.

Nothing here runs on hardware. The loop (:class:`marlander_lite.deploy.mission.Mission`) is the
one that flies real Crazyflies; only its partners are stand-ins:

* :mod:`.world`: :class:`SimulatedWorld`, the swarm simulator (PyBullet Crazyflie or point mass),
  the plate, one virtual firmware per drone, and the loop's clock (sleeping advances physics);
* :mod:`.virtual_firmware`: the Crazyflie firmware as far as the loop relies on it (commander
  watchdog, setpoint priorities, high-level take-off and land, parameters, arming);
* :mod:`.virtual_crazyflie`: a ``cflib`` ``Crazyflie`` whose radio is that firmware, so cflib's own
  ``Swarm``, ``Commander`` and ``Param`` build every packet;
* :mod:`.mocap`: :class:`SimulatedPoseSource`, the motion-capture system (noise, latency, losses);
* :mod:`.faults`: what goes wrong in a lab (dropout, occlusion, NaN pose, lost link, ...), injected;
* :mod:`.run`: :func:`rehearse`, all of it put together, and :class:`RehearsalResult`, the flight
  checked against the simulator's ground truth.
"""

from marlander_lite.deploy.rehearsal.faults import FAULT_KINDS, FaultSpec
from marlander_lite.deploy.rehearsal.mocap import SimulatedPoseSource
from marlander_lite.deploy.rehearsal.run import RehearsalResult, fault_time_limit, rehearse
from marlander_lite.deploy.rehearsal.world import SimulatedWorld, SimulatorUnavailable, make_simulator

__all__ = [
    "FAULT_KINDS",
    "FaultSpec",
    "RehearsalResult",
    "SimulatedPoseSource",
    "SimulatedWorld",
    "SimulatorUnavailable",
    "fault_time_limit",
    "make_simulator",
    "rehearse",
]
