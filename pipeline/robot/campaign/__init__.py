"""Measurements and robot descriptions in: a campaign ingested, a tracker export imported, the
tracker frame and its units found, a URDF read."""
