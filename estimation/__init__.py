"""Estimation stage: body model, features, discriminative and generative fitting, biometrics."""
