"""skincal.viz"""
