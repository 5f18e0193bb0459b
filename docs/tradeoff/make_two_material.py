"""Write two_material.npz: a 4 x 1 x 1 m beam of 32 x 8 x 8 voxels (0.125 m), stiff (label 1)
except a soft band (label 2) across x in [1.5, 2.5] m.  Run from this folder:

    python make_two_material.py
"""

import numpy as np

import voxflex as vf

labels = np.ones((32, 8, 8), dtype=np.uint8)
labels[12:20] = 2
image = vf.LabelImage(labels, spacing=np.full(3, 0.125), origin=np.zeros(3))
image.save("two_material.npz")
print(image.describe())
