#!/usr/bin/env python3
"""Helpers for building small COLMAP localization test sets (Python 3 stdlib only, no numpy).

Subcommands (all models are COLMAP *text* models; convert binary ones with `colmap model_converter`):
  shared_intrinsics SRC_MODEL
      Print "MODEL PARAMS_CSV" if every camera of the model has the same model, size and params,
      else print "per_image".
  set_db_cameras SRC_MODEL DB
      Overwrite each database camera with the camera the source model gives to an image of that
      camera (matched by image name); fails if two such images disagree.
  map_input SRC_MODEL DB OUT_DIR QUERIES_CSV
      Write a text model with the poses of all non-query images of SRC_MODEL, re-numbered to the
      image and camera ids of DB (matched by image name), no 2D or 3D points: the input of
      `colmap point_triangulator`.
  queries SRC_MODEL QUERIES_CSV OUT_DIR
      Write OUT_DIR/queries_with_intrinsics.txt (NAME MODEL W H PARAMS...) and
      OUT_DIR/queries_gt.txt (NAME QW QX QY QZ TX TY TZ, cam_from_world) from SRC_MODEL.
  compare EST_MODEL REF_MODEL QUERIES_CSV
      Per query: camera-centre distance (model units) and rotation angle (deg) between the two models.
  check_map MAP_MODEL REF_MODEL DB QUERIES_CSV
      Assert the map holds exactly the non-query images, with the reference poses, and that each
      image's 2D points are its database keypoints in order (so POINT2D_IDX == keypoint row).
  cap_features DB MAX_FEATURES
      Keep at most MAX_FEATURES keypoints (and their descriptors) per image: those of largest scale,
      in their original order. (COLMAP's --SiftExtraction.max_num_features keeps whole DoG levels,
      so it overshoots the limit.) Run before matching.
  sequence_check MODEL
      For an image sequence (sorted by name): the largest rotation and the largest camera step
      between consecutive images, the step relative to the median step. Flags broken joins.
  mapillary_gps IMAGE_DIR
      Print NAME LAT LON ALT for every *.jpg whose EXIF holds Mapillary's JSON description
      (MAPLatitude, MAPLongitude, MAPAltitude).
  gps_scale MODEL GPS_TXT
      Print the scale that makes camera displacements (images 5 apart) match GPS (NAME LAT LON ALT),
      as the median ratio, and the min / median / max of the remaining local ratio.
  camera_height_scale MODEL HEIGHT
      For a camera mounted at a known HEIGHT (metres) above a flat road, looking along it: print the
      scale that makes the camera's height above the road HEIGHT, from the road points (3D points
      seen in the bottom quarter and middle half of an image, in front of the camera), as the
      median height in the camera frame; then that height's quartiles over the median.
  trim_db DB
      Delete matches and two_view_geometries and VACUUM.
  db_summary DB
      Print image count and keypoint statistics.
"""
import math
import os
import re
import sqlite3
import struct
import sys

CAMERA_MODELS = {  # COLMAP model id -> (name, number of params)
    0: ('SIMPLE_PINHOLE', 3), 1: ('PINHOLE', 4), 2: ('SIMPLE_RADIAL', 4), 3: ('RADIAL', 5),
    4: ('OPENCV', 8), 5: ('OPENCV_FISHEYE', 8), 6: ('FULL_OPENCV', 12), 7: ('FOV', 5),
    8: ('SIMPLE_RADIAL_FISHEYE', 4), 9: ('RADIAL_FISHEYE', 5), 10: ('THIN_PRISM_FISHEYE', 12),
}
MODEL_IDS = {name: model_id for model_id, (name, _) in CAMERA_MODELS.items()}


def fail(message):
    sys.exit('colmap_set_tool: ' + message)


def data_lines(path):
    """Lines of a COLMAP text file without comments (empty lines kept: they are empty POINTS2D)."""
    with open(path) as f:
        return [line.rstrip('\n') for line in f if not line.startswith('#')]


def read_cameras(model_dir):
    cameras = {}
    for line in data_lines(os.path.join(model_dir, 'cameras.txt')):
        p = line.split()
        if p:
            cameras[int(p[0])] = (p[1], int(p[2]), int(p[3]), [float(v) for v in p[4:]])
    return cameras


def read_images(model_dir):
    """image name -> dict(id, q (w,x,y,z), t, camera_id, xy: list of 2D point coordinates)."""
    lines = data_lines(os.path.join(model_dir, 'images.txt'))
    while lines and not lines[0].strip():  # tolerate blank lines before the first image
        lines.pop(0)
    images = {}
    for i in range(0, len(lines), 2):
        p = lines[i].split()
        if not p:
            continue
        points = lines[i + 1].split() if i + 1 < len(lines) else []
        images[p[9]] = dict(id=int(p[0]), q=[float(v) for v in p[1:5]], t=[float(v) for v in p[5:8]],
                            camera_id=int(p[8]),
                            xy=[(float(points[k]), float(points[k + 1])) for k in range(0, len(points), 3)])
    return images


def parse_names(csv):
    names = [n for n in csv.split(',') if n]
    if not names:
        fail('empty query list')
    return names


def db_cameras(db):
    return {cid: (CAMERA_MODELS[m][0], w, h, list(struct.unpack('<%dd' % (len(blob) // 8), blob)))
            for cid, m, w, h, blob in db.execute('SELECT camera_id, model, width, height, params FROM cameras')}


def db_images(db):
    return {name: (image_id, camera_id)
            for image_id, name, camera_id in db.execute('SELECT image_id, name, camera_id FROM images')}


def rotation(q):
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]


def camera_centre(image):
    r, t = rotation(image['q']), image['t']
    return [-sum(r[j][i] * t[j] for j in range(3)) for i in range(3)]


def pose_error(est, ref):
    """(camera-centre distance in model units, rotation angle in degrees)."""
    ne = math.sqrt(sum(v * v for v in est['q']))
    nr = math.sqrt(sum(v * v for v in ref['q']))
    cos_half = min(1.0, abs(sum(a * b for a, b in zip(est['q'], ref['q']))) / (ne * nr))
    return math.dist(camera_centre(est), camera_centre(ref)), 2 * math.degrees(math.acos(cos_half))


def format_params(params):
    return ' '.join(repr(v) for v in params)


def shared_intrinsics(src):
    cameras = set((m, w, h, tuple(p)) for m, w, h, p in read_cameras(src).values())
    if len(cameras) != 1:
        print('per_image')
        return
    model, _, _, params = cameras.pop()
    print(model, ','.join(repr(v) for v in params))


def camera_for_db_camera(src, db):
    """DB camera id -> source camera, via the names of the images using it."""
    cameras, images, ids = read_cameras(src), read_images(src), db_images(db)
    result = {}
    for name, image in images.items():
        if name not in ids:
            continue
        camera = cameras[image['camera_id']]
        db_camera_id = ids[name][1]
        if result.setdefault(db_camera_id, camera) != camera:
            fail('images of database camera %d have different source cameras' % db_camera_id)
    return result


def set_db_cameras(src, db_path):
    db = sqlite3.connect(db_path)
    for camera_id, (model, w, h, params) in camera_for_db_camera(src, db).items():
        db.execute('UPDATE cameras SET model=?, width=?, height=?, params=?, prior_focal_length=1 '
                   'WHERE camera_id=?',
                   (MODEL_IDS[model], w, h, struct.pack('<%dd' % len(params), *params), camera_id))
    db.commit()


def map_input(src, db_path, out, queries_csv):
    queries = set(parse_names(queries_csv))
    db = sqlite3.connect(db_path)
    images, ids, dbcams = read_images(src), db_images(db), db_cameras(db)
    missing = sorted(queries - set(images))
    if missing:
        fail('queries not in source model: ' + ','.join(missing))
    cameras = camera_for_db_camera(src, db)
    os.makedirs(out, exist_ok=True)
    used = set()
    with open(os.path.join(out, 'images.txt'), 'w') as f:
        for name in sorted(images):
            if name in queries:
                continue
            if name not in ids:
                fail('image %s of the source model is not in the database' % name)
            image_id, camera_id = ids[name]
            used.add(camera_id)
            im = images[name]
            f.write('%d %s %s %d %s\n\n' % (image_id, format_params(im['q']), format_params(im['t']),
                                            camera_id, name))
    with open(os.path.join(out, 'cameras.txt'), 'w') as f:
        for camera_id in sorted(used):
            model, w, h, params = cameras[camera_id]
            db_model, db_w, db_h, db_params = dbcams[camera_id]
            if (model, w, h) != (db_model, db_w, db_h):
                fail('camera %d: model/size %s differs from database %s' %
                     (camera_id, (model, w, h), (db_model, db_w, db_h)))
            f.write('%d %s %d %d %s\n' % (camera_id, model, w, h, format_params(params)))
    open(os.path.join(out, 'points3D.txt'), 'w').close()
    print('map input: %d images, %d camera(s)' % (len(images) - len(queries), len(used)))


def queries(src, queries_csv, out):
    names = parse_names(queries_csv)
    cameras, images = read_cameras(src), read_images(src)
    with open(os.path.join(out, 'queries_with_intrinsics.txt'), 'w') as fi, \
            open(os.path.join(out, 'queries_gt.txt'), 'w') as fg:
        for name in names:
            if name not in images:
                fail('query %s not in %s' % (name, src))
            im = images[name]
            model, w, h, params = cameras[im['camera_id']]
            fi.write('%s %s %d %d %s\n' % (name, model, w, h, format_params(params)))
            fg.write('%s %s %s\n' % (name, format_params(im['q']), format_params(im['t'])))


def compare(est_dir, ref_dir, queries_csv):
    est, ref = read_images(est_dir), read_images(ref_dir)
    for name in parse_names(queries_csv):
        if name not in est:
            print('%s NOT_REGISTERED' % name)
            continue
        dpos, drot = pose_error(est[name], ref[name])
        print('%s %.6f %.4f' % (name, dpos, drot))


def check_map(map_dir, ref_dir, db_path, queries_csv):
    queries = set(parse_names(queries_csv))
    db = sqlite3.connect(db_path)
    ids = db_images(db)
    keypoints = {}
    for image_id, n, cols, data in db.execute('SELECT image_id, rows, cols, data FROM keypoints'):
        values = struct.unpack('<%df' % (n * cols), data)
        keypoints[image_id] = [(values[i * cols], values[i * cols + 1]) for i in range(n)]
    mapped, ref = read_images(map_dir), read_images(ref_dir)
    expected = set(ref) - queries
    if set(mapped) != expected:
        fail('map images %s != expected %s' % (sorted(mapped), sorted(expected)))
    worst_pos, worst_rot = 0.0, 0.0
    for name, im in mapped.items():
        if im['id'] != ids[name][0]:
            fail('%s: map image id %d != database id %d' % (name, im['id'], ids[name][0]))
        kps = keypoints[im['id']]
        if len(im['xy']) != len(kps):
            fail('%s: %d 2D points but %d keypoints' % (name, len(im['xy']), len(kps)))
        if any(abs(a[0] - b[0]) > 1e-3 or abs(a[1] - b[1]) > 1e-3 for a, b in zip(im['xy'], kps)):
            fail('%s: 2D point coordinates differ from the database keypoints' % name)
        dpos, drot = pose_error(im, ref[name])
        worst_pos, worst_rot = max(worst_pos, dpos), max(worst_rot, drot)
    if worst_pos > 1e-6 or worst_rot > 1e-4:
        fail('map poses moved away from the reference: %.3g units, %.3g deg' % (worst_pos, worst_rot))
    print('map check ok: %d images, ids and 2D points match the database keypoints, poses unchanged '
          '(max %.1e units, %.1e deg)' % (len(mapped), worst_pos, worst_rot))


def keypoint_scale(kp):
    """Scale of a COLMAP keypoint row: (x, y), (x, y, scale, orientation) or (x, y, a11, a12, a21, a22)."""
    if len(kp) == 4:
        return kp[2]
    if len(kp) == 6:
        return 0.5 * (math.hypot(kp[2], kp[4]) + math.hypot(kp[3], kp[5]))
    return 0.0


def cap_features(db_path, max_features):
    max_features = int(max_features)
    db = sqlite3.connect(db_path)
    if db.execute('SELECT COUNT(*) FROM matches').fetchone()[0]:
        fail('cap_features must run before matching')
    rows = db.execute('SELECT k.image_id, k.rows, k.cols, k.data, d.cols, d.data FROM keypoints k '
                      'JOIN descriptors d ON k.image_id = d.image_id').fetchall()
    for image_id, n, kcols, kdata, dcols, ddata in rows:
        if n <= max_features:
            continue
        kps = struct.unpack('<%df' % (n * kcols), kdata)
        kps = [kps[i * kcols:(i + 1) * kcols] for i in range(n)]
        keep = sorted(sorted(range(n), key=lambda i: -keypoint_scale(kps[i]))[:max_features])
        new_k = b''.join(kdata[i * kcols * 4:(i + 1) * kcols * 4] for i in keep)
        new_d = b''.join(ddata[i * dcols:(i + 1) * dcols] for i in keep)
        db.execute('UPDATE keypoints SET rows=?, data=? WHERE image_id=?', (len(keep), new_k, image_id))
        db.execute('UPDATE descriptors SET rows=?, data=? WHERE image_id=?', (len(keep), new_d, image_id))
    db.commit()


def sequence_check(model_dir):
    images = read_images(model_dir)
    names = sorted(images)
    errors = [(pose_error(images[a], images[b]), a, b) for a, b in zip(names, names[1:])]
    (_, rot), rot_a, rot_b = max(errors, key=lambda e: e[0][1])
    (step, _), step_a, step_b = max(errors, key=lambda e: e[0][0])
    median_step = sorted(e[0][0] for e in errors)[len(errors) // 2]
    print('largest rotation between consecutive images %.1f deg (%s -> %s); largest step %.3g '
          '(%s -> %s) = %.1f x the median step %.3g' % (rot, rot_a, rot_b, step, step_a, step_b,
                                                        step / median_step, median_step))


def mapillary_gps(image_dir):
    for name in sorted(os.listdir(image_dir)):
        if not name.lower().endswith('.jpg'):
            continue
        with open(os.path.join(image_dir, name), 'rb') as f:
            head = f.read(1 << 16).decode('latin-1')
        values = [re.search(r'"%s":"([-0-9.]+)"' % key, head) for key in
                  ('MAPLatitude', 'MAPLongitude', 'MAPAltitude')]
        if all(values):
            print(name, *(v.group(1) for v in values))


def gps_scale(model_dir, gps_path, window=5):
    """Scale that makes the model's camera displacements match GPS ones (median over windows).

    Compares displacements between images `window` apart (sorted by name) that moved more than
    5 m by GPS: this averages out GPS noise better than consecutive steps, and the median ignores
    the few windows where SfM scale drifts. Prints the scale, then the min / median / max of the
    local ratio GPS / scaled-model displacement. East/north use a local tangent plane.
    """
    gps = [line.split() for line in open(gps_path) if line.strip()]
    lat0 = float(gps[0][1])
    metres_per_deg_lat = 111132.954 - 559.822 * math.cos(2 * math.radians(lat0))
    metres_per_deg_lon = 111319.49 * math.cos(math.radians(lat0))
    local = {name: (float(lon) * metres_per_deg_lon, float(lat) * metres_per_deg_lat, float(alt))
             for name, lat, lon, alt in (g[:4] for g in gps)}
    images = read_images(model_dir)
    names = sorted(n for n in images if n in local)
    centres = {n: camera_centre(images[n]) for n in names}
    pairs = list(zip(names, names[window:]))
    ratios = sorted(math.dist(local[a], local[b]) / math.dist(centres[a], centres[b])
                    for a, b in pairs if math.dist(local[a], local[b]) > 5)
    scale = ratios[len(ratios) // 2]
    print('%.9g %.2f %.2f %.2f' % (scale, ratios[0] / scale, 1.0, ratios[-1] / scale))


def read_points3d(model_dir):
    """point id -> (x, y, z)."""
    points = {}
    for line in data_lines(os.path.join(model_dir, 'points3D.txt')):
        p = line.split()
        if p:
            points[int(p[0])] = tuple(float(v) for v in p[1:4])
    return points


def camera_height_scale(model_dir, height):
    cameras, points = read_cameras(model_dir), read_points3d(model_dir)
    lines = [line for line in data_lines(os.path.join(model_dir, 'images.txt'))]
    while lines and not lines[0].strip():
        lines.pop(0)
    heights = []
    for i in range(0, len(lines) - 1, 2):
        p = lines[i].split()
        if not p:
            continue
        r, t = rotation([float(v) for v in p[1:5]]), [float(v) for v in p[5:8]]
        _, width, image_height, _ = cameras[int(p[8])]
        obs = lines[i + 1].split()
        for k in range(0, len(obs), 3):
            x, y, point_id = float(obs[k]), float(obs[k + 1]), int(obs[k + 2])
            if point_id < 0 or y < 0.75 * image_height or abs(x - width / 2) > width / 4:
                continue
            world = points[point_id]
            cam = [sum(r[row][j] * world[j] for j in range(3)) + t[row] for row in range(3)]
            if cam[2] > 0 and cam[1] > 0:
                heights.append(cam[1])
    if len(heights) < 100:
        fail('only %d road observations: is the camera looking along a road?' % len(heights))
    heights.sort()
    median = heights[len(heights) // 2]
    print('%.9g %.3f %.3f %d' % (float(height) / median, heights[len(heights) // 4] / median,
                                 heights[3 * len(heights) // 4] / median, len(heights)))


def trim_db(db_path):
    db = sqlite3.connect(db_path)
    db.execute('DELETE FROM matches')
    db.execute('DELETE FROM two_view_geometries')
    db.commit()
    db.execute('VACUUM')
    db.close()


def db_summary(db_path):
    db = sqlite3.connect(db_path)
    n_images = db.execute('SELECT COUNT(*) FROM images').fetchone()[0]
    n_cameras = db.execute('SELECT COUNT(*) FROM cameras').fetchone()[0]
    kp = [r for (r,) in db.execute('SELECT rows FROM keypoints')]
    desc = [r for (r,) in db.execute('SELECT rows FROM descriptors')]
    if kp != desc:
        fail('keypoint and descriptor counts differ')
    print('%d images, %d camera(s), keypoints per image min %d / mean %.0f / max %d, total %d' %
          (n_images, n_cameras, min(kp), sum(kp) / len(kp), max(kp), sum(kp)))


COMMANDS = {
    'shared_intrinsics': (shared_intrinsics, 1), 'set_db_cameras': (set_db_cameras, 2),
    'map_input': (map_input, 4), 'queries': (queries, 3), 'compare': (compare, 3),
    'check_map': (check_map, 4), 'cap_features': (cap_features, 2), 'sequence_check': (sequence_check, 1), 'mapillary_gps': (mapillary_gps, 1), 'gps_scale': (gps_scale, 2),
    'camera_height_scale': (camera_height_scale, 2),
    'trim_db': (trim_db, 1), 'db_summary': (db_summary, 1),
}

if __name__ == '__main__':
    if len(sys.argv) < 2 or sys.argv[1] not in COMMANDS or len(sys.argv) - 2 != COMMANDS[sys.argv[1]][1]:
        sys.exit(__doc__)
    COMMANDS[sys.argv[1]][0](*sys.argv[2:])
