"""Published figures to compare against, as data (seconds, voxel counts).

* Thesis Table 3.1 (Dai 2020, §3.6.2; SIGGRAPH 2018): C++ on an Intel Xeon E5 1630 3.7 GHz quad
  core, 32 GB, Ubuntu 14.04. "Total" is the whole curved-layer decomposition (peeling field + growth
  with shadow prevention); "surfaces" includes polygonization and trimming. Models were hollowed.
* Fig. 3.16: greedy CFA on the Armadillo (no shadow prevention).
* Thesis Table 4.2 (§4.5.3): motion planning of one tool-path; "init" = IK ladder + graph search,
  "optm" = jerk optimization by local filtering (Alg. 6), "dense" = a ladder with θ every degree.
* The authors' public C++ code (VoxelMultiAxisAM) run on the shared models on a 2-core machine of
  this project's kind (figures from ../shared/DESIGN.md, the project's design notes): the figures to beat on the same model and voxel size.
"""

from __future__ import annotations

PAPER_MACHINE = "Intel Xeon E5 1630 3.7 GHz, 4 cores, 32 GB RAM, Ubuntu 14.04, C++"

#: Table 3.1 rows: voxels, seconds of peeling field / shadow prevention / total decomposition,
#: working surfaces, tool-paths; missed voxels (None = not reported; "null" in the thesis means 0).
TABLE_3_1: dict[str, dict[str, float | None]] = {
    "bunny": {"voxels": 97_532, "peeling": 7.24, "shadow": 171.57, "total": 203.90, "surfaces": 888.72, "toolpaths": 51.09, "missed": 0},
    "candelabra": {"voxels": 186_735, "peeling": 9.92, "shadow": 158.83, "total": 233.90, "surfaces": 204.01, "toolpaths": 131.84, "missed": 0},
    "armadillo": {"voxels": 540_689, "peeling": 34.18, "shadow": 3_035.76, "total": 3_639.21, "surfaces": 1_930.95, "toolpaths": 567.53, "missed": 0},
    "woman-pully": {"voxels": 185_815, "peeling": 10.18, "shadow": 436.07, "total": 537.06, "surfaces": 1_258.14, "toolpaths": 167.75, "missed": 0},
    "mech-part": {"voxels": 186_723, "peeling": None, "shadow": 1_200.05, "total": 1_252.43, "surfaces": 444.82, "toolpaths": 126.72, "missed": 0},
    "fertility": {"voxels": 77_064, "peeling": 3.79, "shadow": 207.04, "total": 232.76, "surfaces": None, "toolpaths": None, "missed": 511},
}

#: Fig. 3.16 (figure as quoted in ../shared/DESIGN.md): greedy CFA without shadow prevention on the Armadillo.
GCFA_ARMADILLO = {"voxels": 540_689, "growing": 32.8, "missed": 10_752}

#: Table 4.2: waypoints and seconds of ladder init (IK + graph search), jerk optimization, total, dense graph.
TABLE_4_2: dict[str, dict[str, float]] = {
    "WS1": {"waypoints": 2_545, "init": 86.0, "optm": 30.0, "total": 116.0, "dense": 1_837.0},
    "WS2": {"waypoints": 4_681, "init": 265.0, "optm": 58.0, "total": 322.0, "dense": 3_283.0},
}

AUTHORS_MACHINE = "2 cores (this project's machine kind), C++ VoxelMultiAxisAM with libigl/CGAL/qhull, GUI stripped"

#: The authors' C++ on the shared models, keyed by (model, voxel mm, method); None = not measured.
AUTHORS_CPP: dict[tuple[str, float, str], dict[str, float | None]] = {
    ("bunny", 1.0, "pg-sp-gcfa"): {"voxels": 124_918, "peeling": 2.2, "growing": 23.0, "missed": 3, "layers": 95, "trimming": 362.8, "written": 73, "extracted": 93},
    ("bunny", 1.0, "sp-gcfa"): {"voxels": 124_918, "peeling": None, "growing": 108.3, "missed": 3, "layers": 86, "trimming": 347.0, "written": 78, "extracted": 84},
    ("kitten", 0.8, "pg-sp-gcfa"): {"voxels": 66_901, "peeling": 1.5, "growing": 9.4, "missed": 0, "layers": 80, "trimming": 86.6, "written": 68, "extracted": 78},
    ("fertility", 0.8, "pg-sp-gcfa"): {"voxels": 90_501, "peeling": 2.7, "growing": 77.7, "missed": 460, "layers": 149, "trimming": 139.8, "written": 134, "extracted": 147},
    ("rocker-arm", 0.8, "pg-sp-gcfa"): {"voxels": 60_454, "peeling": 2.5, "growing": 14.4, "missed": 3, "layers": 117, "trimming": 117.0, "written": 101, "extracted": 115},
    ("fandisk", 0.8, "pg-sp-gcfa"): {"voxels": 73_572, "peeling": 0.6, "growing": 321.7, "missed": 3, "layers": 97, "trimming": 56.9, "written": 93, "extracted": 95},
    # measured here on 2026-11-28 (not in DESIGN.md): the authors' field code (voxel.cpp, bsp_tree.cpp, bst.cpp
    # unchanged) built headless with CGAL, qhull and Eigen from Debian and a small stand-in for the four libigl
    # calls of its field part (pseudonormal signed distance on a CGAL AABB tree, OBJ reading); it gives the
    # DESIGN.md figures above exactly (bunny 3 missed / 95 layers, kitten 0 / 80, rocker-arm 3 / 117). The cow
    # turned 90° about the vertical: in its own frame the authors' voxelizer marks 4 voxels outside the mesh
    # on the grid's border and crashes (ours misses 20 in both frames). Dual contouring and trimming not built.
    ("cheburashka", 0.8, "pg-sp-gcfa"): {"voxels": 66_730, "peeling": 1.48, "growing": 50.4, "missed": 293, "layers": 115, "trimming": None, "written": None, "extracted": None},
    ("cow", 0.8, "pg-sp-gcfa"): {"voxels": 43_074, "peeling": 0.69, "growing": 82.0, "missed": 111, "layers": 99, "trimming": None, "written": None, "extracted": None},
    ("homer", 0.8, "pg-sp-gcfa"): {"voxels": 34_655, "peeling": 1.15, "growing": 8.4, "missed": 3, "layers": 94, "trimming": None, "written": None, "extracted": None},
}

#: Thesis Table 2.1 (§2.5, RoboFDM; machine not stated): facets of the decomposed model, decomposition
#: seconds, fabrication minutes on the UR3 cell.
TABLE_2_1: dict[str, dict[str, float]] = {
    "bunny": {"facets": 10_000, "decomposition": 171.0, "fabrication_min": 152.0},
    "armadillo": {"facets": 17_142, "decomposition": 269.0, "fabrication_min": 263.0},
    "hanging-ball": {"facets": 5_984, "decomposition": 156.0, "fabrication_min": 85.0},
}
