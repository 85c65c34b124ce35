"""Offscreen hair rasteriser: polylines and meshes in, images and videos out. No physics."""
