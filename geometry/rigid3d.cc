#include "geometry/rigid3d.h"
