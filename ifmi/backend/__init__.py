"""The shared back end: relative pose with model selection, bundle adjustment, rolling-shutter compensation."""
