"""skincal.sim"""
