"""The robots and their physics, the bottom layer: MJCF models (:mod:`.robots`), the two
simulators (:mod:`.native`, MJX), rollouts and the transitions they record."""
