"""skynav.datasets"""
