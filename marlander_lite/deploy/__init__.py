"""Deployment on Crazyflies with a motion-capture system (paper Sec. III-A, Fig. 2, Sec. IV-A), and its rehearsal.

The pieces, each in its own module:

* :mod:`.config` (with :mod:`.schema`): the lab YAML: URIs, rigid bodies, rates, limits, geofence, validated;
* :mod:`.pose_sources`: motion capture (``motioncapture``) or the simulated lab, behind one interface;
* :mod:`.estimation`: velocities and angular velocities from poses, data age per body;
* :mod:`.runner`: eq. 2 observation -> exported policy -> clamped velocity setpoints;
* :mod:`.safety`: geofence, stale data, bad poses and actions, lost links, the pre-flight check;
* :mod:`.link`: cflib ``Swarm``: parameters, ``send_extpose``, setpoints, land, motors off;
* :mod:`.mission` (with :mod:`.landing`, :mod:`.results`): the fixed-rate loop tying them together;
* :mod:`.flight_log`, :mod:`.plots`: JSON-lines flight logs, and the paper's Fig. 7 drawn from them;
* :mod:`.virtual_firmware`, :mod:`.virtual_crazyflie`, :mod:`.sim_world`, :mod:`.faults`,
  :mod:`.rehearsal`: the simulated lab (cflib's packets decoded by a firmware model that flies a
  simulated swarm), faults to inject, and :func:`rehearse`;
* :mod:`.commands`: ``marlander deploy`` (hardware) and ``marlander deploy --sim`` (rehearsal).

See ``docs/lab_guide.md`` for the lab procedure.
"""

from marlander_lite.deploy.config import EXAMPLE_CONFIG, ConfigError, LabConfig, load_lab_config
from marlander_lite.deploy.faults import FAULT_KINDS, FaultSpec
from marlander_lite.deploy.flight_log import FlightLog, read_flight_log
from marlander_lite.deploy.mission import Mission
from marlander_lite.deploy.rehearsal import RehearsalResult, rehearse
from marlander_lite.deploy.results import MissionResult

__all__ = [
    "EXAMPLE_CONFIG",
    "FAULT_KINDS",
    "ConfigError",
    "FaultSpec",
    "FlightLog",
    "LabConfig",
    "Mission",
    "MissionResult",
    "RehearsalResult",
    "load_lab_config",
    "read_flight_log",
    "rehearse",
]
