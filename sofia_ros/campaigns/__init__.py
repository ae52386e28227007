"""Campaigns: the node graph configured for one of the thesis' test series."""
