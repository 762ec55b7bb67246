"""ROI detection and classification (orbital and rover imagery), roi_detector and ln_builder nodes."""
