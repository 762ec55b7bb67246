"""ROI detection and classification (orbital and rover imagery): roi_detector, ln_builder."""
