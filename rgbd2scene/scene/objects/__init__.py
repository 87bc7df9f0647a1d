"""Objects in the scene besides the tissue (no ``bpy``).

- ``instrument``: the built-in laparoscopic / robotic instrument (shaft, wrist, two jaws) as closed meshes;
- ``motion``: its default motion over the tissue through a trocar, clear of the tissue, in view;
- ``imported``: user meshes (OBJ, PLY, STL, GLB), poses and keyframe / path-file motions;
- ``assemble``: ids, geometry files and tracked frames from a scene configuration
  (:mod:`rgbd2scene.scene.config`).
"""
