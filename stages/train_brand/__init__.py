"""train_brand — Voice Puppetry (paper 002): entropic facial HMM, voice remapping (entry: train_brand.py)."""
