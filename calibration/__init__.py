"""skynav.calibration"""
