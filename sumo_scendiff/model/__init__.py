# scenario autoencoder (section 3.1, appendix C)
from .autoencoder import AutoencoderConfig, ScenarioAutoencoder  # noqa: F401
from .blocks import Downsample, ResnetBlock, Upsample  # noqa: F401
from .detection import DecodedBoxes, DetectionLossConfig, decode_boxes, detection_loss, threshold_boxes  # noqa: F401
