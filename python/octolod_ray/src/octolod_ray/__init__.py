"""Run octolod's sharded build (plan, one task per shard, merge) on a Ray cluster."""

__version__ = "0.1.0"
