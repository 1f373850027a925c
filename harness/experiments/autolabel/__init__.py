"""Labels for free: where three or more calibrated cameras agree on a ball, its reprojection is a label in every camera.

``framesets.py`` reads a recording's frame sets offline (every one, in order), ``consensus.py`` decides
which frame sets the cameras agree on and what each camera's label and hard negatives are, ``output.py``
writes them as a COCO data set (``rt2 label --auto``), ``study.py`` measures them against the truth on
the simulated lab and the semi-real caliscope frame sets (``rt2 eval autolabel``). docs/label.md.
"""
