"""Experiments of the paper (Sec. IV): controllers, the trial protocol, metrics, tables and figures.

=======================  ==================================================================
paper                    code
=======================  ==================================================================
Sec. IV-B/C MARLander    :class:`~marlander_lite.experiments.controllers.MARLanderController`
Sec. IV-D baseline       :class:`~marlander_lite.experiments.controllers.PIDAPFController`
                         (the planner is :mod:`marlander_lite.experiments.apf`)
Sec. IV-E MorphoLander   :class:`~marlander_lite.experiments.controllers.SingleAgentAPFController`
trials, conditions       :mod:`marlander_lite.experiments.protocol`
success, precision, time :mod:`marlander_lite.experiments.metrics`
Tables I and II          :mod:`marlander_lite.experiments.tables`
Fig. 7                   :mod:`marlander_lite.experiments.figures`
docs/reproduction.md     :mod:`marlander_lite.experiments.includes` (generated blocks)
``marlander reproduce``  :mod:`marlander_lite.experiments.commands`
=======================  ==================================================================
"""
