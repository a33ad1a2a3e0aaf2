"""skynav.pipeline"""
