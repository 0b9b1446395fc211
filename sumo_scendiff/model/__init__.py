"""The model: detection autoencoder (autoencoder.py, detection.py), EDM (edm.py), UNet (unet.py),
latent diffusion wrapper (diffusion.py), checkpoints (checkpoint.py)."""
