"""Phase 2: the VAE latent space (paper Table I) and the decoder as the map D (see :mod:`.vae`)."""
from latentune.latent.vae import (BETA_DET, BETA_VAE, DEFAULT_KIND, KINDS, LatentError, LatentSpace,
                                  default_latent_dim)

__all__ = ["LatentSpace", "LatentError", "KINDS", "DEFAULT_KIND", "BETA_VAE", "BETA_DET",
           "default_latent_dim"]
