#include "model/reconstruction.h"
