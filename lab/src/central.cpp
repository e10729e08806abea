// TODO(contract): see include/gyrotherm/lab/*.h
