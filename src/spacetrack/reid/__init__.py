"""Re-identification: the Table 1 appearance CNN, its crops, training on rendered identities, the encoder."""

from spacetrack.reid.crops import Cropper
from spacetrack.reid.encoder import Encoder
from spacetrack.reid.network import ReidNet

__all__ = ["Cropper", "Encoder", "ReidNet"]
