#!/bin/sh
# Makes vdb_tool_shapes.vdb, the level sets of vdb_tool.json, with OpenVDB's own command-line
# tool (Debian/Ubuntu package libopenvdb-tools), so that the gallery has a file written by
# another program than Penumbra:
#   - "difference_Dodecahedron": a dodecahedron with a spherical bite taken out of one corner
#     (vdb_tool's CSG difference, which rebuilds the narrow band afterwards);
#   - "ball": a sphere of radius 0.45 centred at (-0.6, 0, 0.6); tests/test_scene.cpp sets its
#     shadow against the same sphere built by Penumbra.
# Voxels of 0.02, half width 3, values stored as 16-bit floats (bits=16): about 260 KB.
# Run from anywhere; the file is written next to this script.
set -eu
cd "$(dirname "$0")"
vdb_tool \
    -platonic faces=12 scale=0.5 center="(0.6,0,0.5)" voxel=0.02 width=3 \
    -sphere r=0.3 center="(0.75,-0.25,0.75)" voxel=0.02 width=3 \
    -difference vdb=1,0 \
    -sphere r=0.45 center="(-0.6,0,0.6)" voxel=0.02 width=3 name=ball \
    -write bits=16 codec=blosc vdb_tool_shapes.vdb
