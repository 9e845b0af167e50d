#include "model/colmap_io.h"
