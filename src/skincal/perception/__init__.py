"""skincal.perception"""
