"""Features: ImageNet encoders of the street views and their on-disk cache."""
