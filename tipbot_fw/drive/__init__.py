"""Driving: a course file, the drive plan made of it, the path follower, the remotes (UDP and
the EV3 IR remote). The cores see only the reference rows a plan makes."""
