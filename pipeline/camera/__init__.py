"""Camera models (additional parameters) and conversions between baarda's camera and other tools'."""
