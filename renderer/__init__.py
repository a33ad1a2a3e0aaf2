"""skynav.renderer"""
