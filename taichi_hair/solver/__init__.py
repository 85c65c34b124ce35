"""Kmoch's loop: the step's stages and drivers, contacts, pins, hair-hair interaction, the stability bound, the control arrays and the Simulator."""
