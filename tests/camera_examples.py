"""Example calibrations of every camera model, shared by the tests.

Parameters are of the size real calibrations have (the Kannala-Brandt one is
the published TUM-VI camera); they are not tuned to make anything pass.
"""

from __future__ import annotations

from ifmi.geometry.camera import model_from_direct_polynomial
from ifmi.geometry.camera_models import (
    DoubleSphereModel,
    EquirectangularModel,
    ExtendedUnifiedModel,
    KannalaBrandtModel,
    PinholeModel,
    UnifiedModel,
)

EXAMPLES = {
    # Mei model of a wide fisheye with strong barrel distortion (OpenCV's omnidir style).
    "omni-radtan": UnifiedModel(0.9, (260.0, 258.0), (319.5, 239.8), (480, 640),
                                (-0.28, 0.07, 2e-4, -1e-4)),
    # xi > 1: the valid region is a disc inside the image, field of view beyond 180 degrees.
    "omni-wide": UnifiedModel(1.3, (300.0, 300.0), (320.2, 239.6), (480, 640)),
    "pinhole-radtan": PinholeModel.create((400.0, 402.0), (319.5, 239.5), (480, 640),
                                          (-0.2, 0.05, 1e-3, -5e-4)),
    "eucm": ExtendedUnifiedModel(0.63, 1.04, (380.0, 381.0), (376.0, 240.0), (480, 752)),
    "ds": DoubleSphereModel(-0.2, 0.59, (313.0, 314.0), (376.0, 240.0), (480, 752)),
    # TUM-VI's calibrated Kannala-Brandt camera (512 x 512).
    "kb": KannalaBrandtModel((190.97847715128717, 190.9733070521226), (254.93170605935475, 256.8974428996504),
                             (512, 512), (0.0034823894022493434, 0.0007150348452162257,
                                          -0.0020532361418706202, 0.00020293673591811182)),
    "equirectangular": EquirectangularModel((160, 320)),
    "ocamcalib": model_from_direct_polynomial([-120.0, 0.0, 2.1e-3, -1.2e-6, 2.0e-9], center=(241.2, 318.7),
                                              size=(480, 640), affine=(1.0012, 0.0021, -0.0017)),
}
