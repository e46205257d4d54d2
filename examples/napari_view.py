"""
The demo in napari
==================

The plugin ``hrvptm`` (package ``hrvptm_napari``, installed by ``./setup.sh`` or
``pip install -e '.[napari]'``) opens a study report with its volumes, particles, tracks,
displacement vectors, strain components on the field grid and the true particles, all in µm
in the object frame with the frame index as the first axis. From a shell::

    .venv/bin/hrvptm demo -o out/demo
    .venv/bin/napari --plugin hrvptm out/demo

The same from Python, with a screenshot. This page is not executed when the site is built (it
needs a display; headless, run it under a virtual X server, ``xvfb-run -a python
napari_view.py``, with Qt's ``xcb`` platform: the ``offscreen`` platform has no OpenGL
context).

The demo's last frame in 3D: the reconstructed volume, the detected particles (yellow
circles), the true ones (magenta crosses) and the tracks:

.. image:: /_static/demo_napari.png
   :alt: napari showing the demo's volume, particles, truth and tracks in 3D
   :width: 560
"""

import napari

viewer = napari.Viewer(show=True)
layers = viewer.open("out/demo", plugin="hrvptm")
print({layer.name: type(layer).__name__ for layer in layers})
viewer.dims.ndisplay = 3
viewer.dims.set_current_step(0, 4)  # the last of the demo's five frames
viewer.camera.angles = (0, -30, 60)
viewer.screenshot("demo_napari.png", canvas_only=True)
