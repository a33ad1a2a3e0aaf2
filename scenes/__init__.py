"""skynav.scenes"""
