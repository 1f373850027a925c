"""``rt2 label``: label ball frames in a browser page (docs/label.md).

``frames`` opens a folder / video / session log, ``suggest`` picks the frames to label next, ``store``
keeps the labels in COCO on disk, ``training`` runs ``rt2 train`` as a child, ``session`` ties them
together and ``server`` serves the page (``static/``) on 127.0.0.1.
"""
