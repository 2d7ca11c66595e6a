"""Torch datasets over archives and over multi-camera scenes."""
