"""Reference spectral renderer: scenes, cameras, G-buffer, jitted shading, film, batches.

See :mod:`jkatana.render.scene` for the typed scene, :mod:`jkatana.render.scenefile` for its
file, :mod:`jkatana.render.shading` for the shading modes and effects on demand, and ``jkatana demo`` /
``jkatana render`` (:mod:`jkatana.render.commands`).
"""

from jkatana.render.camera import Camera as Camera
from jkatana.render.scene import Scene as Scene
from jkatana.render.scenefile import load_scene as load_scene, scene_from_dict as scene_from_dict
