"""Deployment on Crazyflies with a motion-capture system (paper Sec. III-A, Fig. 2, Sec. IV-A), and its rehearsal.

The pieces, each in its own module:

* :mod:`.config` (with :mod:`.schema`): the lab YAML: URIs, rigid bodies, rates, limits, geofence, validated;
* :mod:`.pose_sources`: motion capture (``motioncapture``) behind the interface the loop reads;
* :mod:`.estimation`: velocities and angular velocities from poses, data age per body;
* :mod:`.runner`: eq. 2 observation -> exported policy -> clamped velocity setpoints, through the safety filter
  (:mod:`marlander_lite.swarm.safety_filter`: separation, soft descent over the pad);
* :mod:`.safety`: geofence, stale data, bad poses and actions, lost links, the pre-flight check;
* :mod:`.link`: cflib ``Swarm``: parameters, ``send_extpose``, setpoints, land, motors off;
* :mod:`.mission` (with :mod:`.landing`, :mod:`.results`): the fixed-rate loop tying them together;
  :mod:`.modes` holds its modes, each drone's phases and the one table of allowed changes for each,
  :mod:`.mission_state` the rest of what it remembers between ticks;
* :mod:`.flight_log`, :mod:`.plots`: JSON-lines flight logs, and the paper's Fig. 7 drawn from them;
* :mod:`.rehearsal` (a package): the simulated lab for rehearsals (cflib's packets decoded by a
  firmware model that flies a simulated swarm, a simulated motion-capture system), faults to
  inject, and :func:`rehearse`; nothing in it runs on hardware;
* :mod:`.commands`: ``marlander deploy`` (hardware) and ``marlander deploy --sim`` (rehearsal).

See ``docs/lab_guide.md`` for the lab procedure.
"""

from marlander_lite.deploy.config import (
    EXAMPLE_CONFIG,
    EXAMPLE_CONFIG_8,
    EXAMPLE_CONFIG_16,
    ConfigError,
    LabConfig,
    load_lab_config,
)
from marlander_lite.deploy.flight_log import FlightLog, read_flight_log
from marlander_lite.deploy.mission import Mission
from marlander_lite.deploy.rehearsal import FAULT_KINDS, FaultSpec, RehearsalResult, rehearse
from marlander_lite.deploy.results import MissionResult

__all__ = [
    "EXAMPLE_CONFIG",
    "EXAMPLE_CONFIG_8",
    "EXAMPLE_CONFIG_16",
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
