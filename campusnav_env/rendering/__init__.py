"""Rendering: the 3D world around the roads, street views at the intersections, top-down maps and contact sheets."""
