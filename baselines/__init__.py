"""equigym baselines: the equivariant diffusion policy trainer and the steering agents.

Heavy dependencies (torch, escnn, stable-baselines3, h5py, safetensors) are needed only here:
``pip install 'equigym[train]'`` (``scripts/setup.sh`` installs them)."""
