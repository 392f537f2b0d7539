"""Coordinate geometry shared by every stage: rig kinematics (joints ⇄ θi, θr, Δφ), MERL
half/difference coordinates, pose sampling patterns and the pinhole camera of image-based
rigs. Pure math.

May import: ``drivers.errors``.
"""
