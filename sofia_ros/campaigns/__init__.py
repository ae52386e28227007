"""Campaigns: the node graph configured for one of the thesis' test series, run in one of three modes and
recorded (registry: every campaign once; recording: direct, executor, processes; graph parameters)."""
