"""The many-target payload of a tracker's schedule: a multi-target tracker whose track lists the neighbours fuse,
and what it admits."""
