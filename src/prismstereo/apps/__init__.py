"""The application layer: the ``prismstereo`` commands, their folder writers, the demo and the thesis tables.

Nothing in the algorithm packages (optics, cameras, rectify, matching, multiview, depth, calibration,
simulate, evaluation, io, viz) imports from here; see tests/test_architecture.py for the layer order.
"""
