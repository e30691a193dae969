"""Reinforcement-learning tasks on the Gymnasium environment of the robot (the ``gym`` extra),
one task a module; importing this package registers them with Gymnasium:

* ``WhiskEye-Localise-v0`` (`localise`): place recognition against a reference map, scored
  by the benchmark's rule.
"""

from vitaplace.engine.tasks import localise

TASKS = (localise,)

for _task in TASKS:
    _task.register()
