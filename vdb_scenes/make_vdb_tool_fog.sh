#!/bin/sh
# Makes vdb_tool_fog.vdb, a fog volume written by OpenVDB's own command-line tool (Debian/Ubuntu
# package libopenvdb-tools) rather than by Penumbra: a sphere of radius 0.4 centred at
# (0, 0, 1.2), voxels of 0.04, band 3 voxels, turned into a fog volume by vdb_tool's -ls2fog
# (density 0 outside, rising linearly to 1 over the interior half of the band, 1 deeper in).
# tests/test_volume.cpp reads it. Run from anywhere; the file is written next to this script.
set -eu
cd "$(dirname "$0")"
vdb_tool \
    -sphere r=0.4 center="(0,0,1.2)" voxel=0.04 width=3 name=cloud \
    -ls2fog name=cloud \
    -write codec=blosc vdb_tool_fog.vdb
