#include "geometry/camera.h"
