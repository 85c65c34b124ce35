"""What the hair lives in: the scene as data, colliders, air and touch, head motion, head meshes and distance grids."""
