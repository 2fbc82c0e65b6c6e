"""Communication models: the slow, lossy acoustic channel the robots share."""

from maptidal.comms.channel import AcousticChannel, ChannelParams, ChannelStats, Delivery, Outage

__all__ = ["AcousticChannel", "ChannelParams", "ChannelStats", "Delivery", "Outage"]
