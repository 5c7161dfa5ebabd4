"""Sensor backends of a node agent: one depth sensor each, behind one contract.

* :mod:`app.nodes.backends.base` — the contract: :class:`~app.nodes.backends.base.Backend`
  (``open`` → :class:`~app.nodes.protocol.SensorInfo`, ``frames`` → ``Frame`` at the
  sensor's rate until ``close``, ``now`` the node clock) and its units and frames.
* :mod:`app.nodes.backends.sim` — the simulated sensor (``--backend sim``).
* :mod:`app.nodes.backends.replay` — plays a recorded part back (``--backend replay``).
* :mod:`app.nodes.backends.k4a` — Azure Kinect / Orbbec Femto through pyk4a, skeletons
  from the Body Tracking SDK via :mod:`app.nodes.backends._k4abt` (``--backend k4a``).

A new backend is chosen in ``make_backend`` of ``app/commands/node.py``; how to write
one: ``docs/research.md`` ("Adding a node backend").
"""
