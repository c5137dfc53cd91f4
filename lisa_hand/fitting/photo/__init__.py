"""Fitting a hand to uncalibrated photographs (``lisa fit-photo``): keypoint detection
(``detect``), masks, the fit and its outputs. Modules are imported by their users; the photo
extra (``pip install -e '.[photo]'``) is needed only for detection."""
