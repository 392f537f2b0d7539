"""Coordinate geometry shared by every stage: rig kinematics (joints ⇄ θi, θr, Δφ), MERL
half/difference coordinates, and pose sampling patterns. Pure math.

May import: ``drivers.errors``.
"""
