"""Skin units: their pose on the chain, the paper's DH form, placements and sensor models."""

from skincal.skin.pose import DH6_NAMES, SkinUnitPose, dh6_from_transform, dh6_to_transform

__all__ = ["DH6_NAMES", "SkinUnitPose", "dh6_from_transform", "dh6_to_transform"]
