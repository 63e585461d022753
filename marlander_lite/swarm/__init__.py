"""Beyond the paper (its future work, Sec. VI): one decentralised policy shared by every drone of a swarm of any size.

=====================================  =============================================================
:mod:`~marlander_lite.swarm.observation`  each drone's input: its eq. 2 observation + its k nearest neighbours
:mod:`~marlander_lite.swarm.vec_env`      a stable-baselines3 VecEnv whose entries are (swarm, drone) pairs
:mod:`~marlander_lite.swarm.policy`       the shared policy flying a whole swarm, from a policy file
:mod:`~marlander_lite.swarm.train`        PPO with parameter sharing over a mixture of swarm sizes
:mod:`~marlander_lite.swarm.memory`       continue a trained run with the previous command as a new input
:mod:`~marlander_lite.swarm.evaluation`   success, error, time, separation and collisions vs N
:mod:`~marlander_lite.swarm.touchdowns`   the speed of every touchdown, on any point mass of the dynamics family
=====================================  =============================================================
"""
