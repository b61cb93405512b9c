"""skincal.control"""
