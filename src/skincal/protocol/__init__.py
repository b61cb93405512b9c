"""skincal.protocol"""
