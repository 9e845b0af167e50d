#include "model/feature_io.h"
