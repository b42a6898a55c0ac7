"""The planar robot-cell tools of seeds 000, 003 and 004, apart from the curved-layer pipeline.

They turn planar work into robot programs on a fixed-orientation print cell: ``cells`` (the cell
description: offset, workspace, nozzle orientation, controller I/O, and the G-code → robot-path
mapping), ``gcode`` (the strict slicer G-code reader), ``levelling`` (bed levelling from a probe
grid) and ``drape`` (DXF designs draped over a surface). The multi-axis planning frames of the
curved-layer pipeline are :mod:`curvslice.workcell`, not these cells. The bead/flow model
(:mod:`curvslice.flow`) stays at the top level because the tool-path stage uses it too.
"""
