"""The robots and their physics, the bottom layer: MJCF models as :class:`robots.Robot`
(:mod:`.robots`, quadrupeds described from the file alone in :mod:`.quadruped`, the Solo12's
closed forms in :mod:`.solo12`), the two simulators (MuJoCo C through :mod:`.native`, MJX),
an end-effector site's kinematics (:mod:`.opspace`), closed-loop rollouts and the
transitions they record (:mod:`.rollout`, :mod:`.dataset`), and rendering
(:mod:`.render`). Imports nothing above it: no task, no loss."""
