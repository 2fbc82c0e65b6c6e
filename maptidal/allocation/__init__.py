"""Decentralised task allocation: CBBA with bid warping over a slow, lossy acoustic channel.

Pure Python and numpy; no simulator needed. See maptidal.allocation.agent for a robot's task manager,
maptidal.allocation.auction for a team over maptidal.comms, and maptidal.allocation.greedy for the
centralised yardstick.
"""
