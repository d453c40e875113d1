"""A training run, top to bottom: ``train`` builds its pieces from the settings and picks its world, ``cloning`` and
``subscribers`` serve it, the worlds (``model_free``, ``model_based``, ``action_space``) say what a step is, and
``loop`` is the one loop they all step in."""
