"""The demo application (``hydropump-demo``), pure: its campaign and what is made of its bags
(:mod:`.campaign`), the Fig. 1 and excavator duty cycles (:mod:`.fig1`, :mod:`.excavator`,
on :mod:`.duty`), the operating map (:mod:`.maps`), the figures (:mod:`.plots`) and the
report (:mod:`.report`). It runs the offline harnesses of :mod:`hydropump_ctrl.experiments`
and the plans' experiments (:mod:`hydropump_ctrl.experiment`); the ROS package runs the
same experiments through the nodes.
"""
