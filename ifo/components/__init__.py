"""The pieces every method composes: supervised training, action choice, sampling of I_s."""
