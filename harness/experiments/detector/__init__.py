"""The ball detector's data: COCO labels, training (``rt2 train``)."""
