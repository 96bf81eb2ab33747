"""Motion: paths between postures along a map, and their files (the rig, BVH and glTF)."""
