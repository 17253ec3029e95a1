// First hits of rays that leave one point (a camera's eye) against a triangle mesh.
//
// The rays are binned by where they cross the plane z = 1 of a frame whose z axis every ray
// points along (a pinhole's image plane); each triangle in front of the eye then meets only the
// rays in the cells under its projected bounding box, and each of those is tested in double
// against the planes through the eye and the triangle's edges, four rays at a time. A triangle
// that reaches behind the eye's plane meets every ray.
// Barycentrics follow embree's convention: the hit is (1 - u - v) a + u b + v c. The nearest hit
// at t > 0 wins; on an exact tie the triangle listed first.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

namespace {

struct Vec3 {
  double x, y, z;
};

inline Vec3 Sub(const Vec3& a, const Vec3& b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline double Dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 Cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline Vec3 Load(const double* p) { return {p[0], p[1], p[2]}; }

// Rays per grid cell on average: fewer cells cost the binning, more the triangles' cell walks.
constexpr double kRaysPerCell = 4.0;
constexpr int64_t kMaxCellsPerAxis = 4096;
// Rays further than this (cosine) from their summed direction land too far out on z = 1.
constexpr double kMinAxisCosine = 0.05;
// Rays tested together (one vector of doubles); a cell's run is padded to a multiple of it.
constexpr int64_t kLanes = 4;
using Lanes = double __attribute__((vector_size(kLanes * sizeof(double))));
using Bits = int64_t __attribute__((vector_size(kLanes * sizeof(int64_t))));
constexpr Lanes zero = {};

inline Lanes LoadLanes(const double* p) {
  Lanes v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void StoreLanes(double* p, Lanes v) { std::memcpy(p, &v, sizeof v); }
inline Lanes Select(Bits mask, Lanes a, Lanes b) {
  return (Lanes)(((Bits)a & mask) | ((Bits)b & ~mask));
}
inline Lanes Abs(Lanes x) { return (Lanes)((Bits)x & INT64_MAX); }

}  // namespace

// vertices (V, 3), faces (F, 3) int64 into vertices, origins (N, 3), dirs (N, 3). Writes face
// (N,) int64 (-1 = miss), t (N,) along dirs (inf = miss), u (N,), v (N,), and, when
// corner_values (F, 3, K) is given, values_out (N, K): the hit face's corner values mixed by the
// hit's barycentrics (0 at a miss). Returns 0, or 1 (then nothing is written) when the origins
// are not all one point or the directions do not all lean along their sum by kMinAxisCosine.
extern "C" int GaeFirstHitsFromPoint(const double* vertices, int64_t num_vertices,
                                     const int64_t* faces, int64_t num_faces,
                                     const double* origins, const double* dirs,
                                     int64_t num_rays, int64_t* face_out, double* t_out,
                                     double* u_out, double* v_out, const double* corner_values,
                                     int64_t num_values, double* values_out) {
  if (num_rays == 0) return 0;
  const Vec3 eye = Load(origins);
  bool shared = true;
  for (int64_t r = 0; r < num_rays; ++r) {
    shared &= (origins[3 * r] == eye.x) & (origins[3 * r + 1] == eye.y) &
              (origins[3 * r + 2] == eye.z);
  }
  if (!shared) return 1;
  // The frame: z along the rays' summed directions, x and y across it.
  Vec3 az = {0.0, 0.0, 0.0};
  for (int64_t r = 0; r < num_rays; ++r) az = {az.x + dirs[3 * r], az.y + dirs[3 * r + 1],
                                              az.z + dirs[3 * r + 2]};
  const double axis_length = std::sqrt(Dot(az, az));
  if (!(axis_length > 0.0)) return 1;
  az = {az.x / axis_length, az.y / axis_length, az.z / axis_length};
  const Vec3 helper = std::fabs(az.x) < 0.5 ? Vec3{1.0, 0.0, 0.0} : Vec3{0.0, 1.0, 0.0};
  Vec3 ax = Cross(helper, az);
  const double ax_length = std::sqrt(Dot(ax, ax));
  ax = {ax.x / ax_length, ax.y / ax_length, ax.z / ax_length};
  const Vec3 ay = Cross(az, ax);

  std::vector<double> px(num_rays), py(num_rays);
  double x0 = std::numeric_limits<double>::infinity(), y0 = x0, x1 = -x0, y1 = -x0;
  bool along = true;
  for (int64_t r = 0; r < num_rays; ++r) {
    const Vec3 d = Load(dirs + 3 * r);
    const double z = Dot(d, az);
    along &= (z > 0.0) & (z * z >= kMinAxisCosine * kMinAxisCosine * Dot(d, d));
    px[r] = Dot(d, ax) / z;
    py[r] = Dot(d, ay) / z;
    x0 = std::min(x0, px[r]);
    x1 = std::max(x1, px[r]);
    y0 = std::min(y0, py[r]);
    y1 = std::max(y1, py[r]);
  }
  if (!along) return 1;

  // Cells of about kRaysPerCell rays over the rays' extent on the plane.
  const double width = std::max(x1 - x0, 1e-12), height = std::max(y1 - y0, 1e-12);
  const double cell = std::sqrt(width * height * kRaysPerCell / double(num_rays));
  const int64_t nx = std::clamp<int64_t>(int64_t(std::ceil(width / cell)), 1, kMaxCellsPerAxis);
  const int64_t ny = std::clamp<int64_t>(int64_t(std::ceil(height / cell)), 1, kMaxCellsPerAxis);
  const double sx = double(nx) / width, sy = double(ny) / height;
  auto cell_x = [&](double x) {
    return std::clamp<int64_t>(int64_t(std::floor((x - x0) * sx)), 0, nx - 1);
  };
  auto cell_y = [&](double y) {
    return std::clamp<int64_t>(int64_t(std::floor((y - y0) * sy)), 0, ny - 1);
  };
  // Each cell's rays in bin order, its run padded to whole lanes with rays of no direction
  // (every triple product 0: never inside by the nearer test), so that the inner loop reads
  // contiguous memory in fixed blocks the compiler vectorises.
  std::vector<int64_t> start(nx * ny + 1, 0), cell_of(num_rays);
  for (int64_t r = 0; r < num_rays; ++r) {
    cell_of[r] = cell_y(py[r]) * nx + cell_x(px[r]);
    ++start[cell_of[r] + 1];
  }
  for (int64_t c = 0; c < nx * ny; ++c) {
    start[c + 1] = start[c] + (start[c + 1] + kLanes - 1) / kLanes * kLanes;
  }
  const int64_t slots = start[nx * ny];
  std::vector<int64_t> order(slots, -1);
  {
    std::vector<int64_t> fill(start.begin(), start.end() - 1);
    for (int64_t r = 0; r < num_rays; ++r) order[fill[cell_of[r]]++] = r;
  }
  std::vector<double> dx(slots, 0.0), dy(slots, 0.0), dz(slots, 0.0);
  for (int64_t i = 0; i < slots; ++i) {
    if (order[i] < 0) continue;
    const double* d = dirs + 3 * order[i];
    dx[i] = d[0], dy[i] = d[1], dz[i] = d[2];
  }
  // The nearest hit so far as the fraction |volume| / |sum| (t = volume / sum), divided out at
  // the end: 1 / 0 stands for no hit. wb, wc: its unnormalised barycentrics.
  std::vector<double> best_volume(slots, 1.0), best_sum(slots, 0.0);
  std::vector<double> best_wb(slots, 0.0), best_wc(slots, 0.0), best_signed_sum(slots, 1.0);
  std::vector<int64_t> best_face(slots, -1);

  // Vertices in the frame, and their crossings of the plane when in front of the eye.
  std::vector<double> depth(num_vertices), vx(num_vertices), vy(num_vertices);
  for (int64_t i = 0; i < num_vertices; ++i) {
    const Vec3 p = Sub(Load(vertices + 3 * i), eye);
    depth[i] = Dot(p, az);
    vx[i] = depth[i] > 0.0 ? Dot(p, ax) / depth[i] : 0.0;
    vy[i] = depth[i] > 0.0 ? Dot(p, ay) / depth[i] : 0.0;
  }
  // A bounding box widened by this fraction of a cell keeps rays on its edge despite rounding.
  const double pad = 1e-6 / std::max(sx, sy);

  for (int64_t f = 0; f < num_faces; ++f) {
    const int64_t ia = faces[3 * f], ib = faces[3 * f + 1], ic = faces[3 * f + 2];
    const double za = depth[ia], zb = depth[ib], zc = depth[ic];
    if (za <= 0.0 && zb <= 0.0 && zc <= 0.0) continue;  // behind the eye: no ray meets it
    int64_t cx0 = 0, cx1 = nx - 1, cy0 = 0, cy1 = ny - 1;
    if (za > 0.0 && zb > 0.0 && zc > 0.0) {
      const double ua = vx[ia], ub = vx[ib], uc = vx[ic];
      const double va = vy[ia], vb = vy[ib], vc = vy[ic];
      const double bx0 = std::min({ua, ub, uc}) - pad, bx1 = std::max({ua, ub, uc}) + pad;
      const double by0 = std::min({va, vb, vc}) - pad, by1 = std::max({va, vb, vc}) + pad;
      if (bx1 < x0 || bx0 > x1 || by1 < y0 || by0 > y1) continue;
      cx0 = cell_x(bx0), cx1 = cell_x(bx1), cy0 = cell_y(by0), cy1 = cell_y(by1);
    }
    // Corners relative to the eye; a ray d passes through the triangle when its three triple
    // products with the edges' planes through the eye share a sign. A shared edge's plane is the
    // same cross product negated exactly, so no ray slips between two triangles.
    const Vec3 a = Sub(Load(vertices + 3 * ia), eye), b = Sub(Load(vertices + 3 * ib), eye);
    const Vec3 c = Sub(Load(vertices + 3 * ic), eye);
    const Vec3 n_bc = Cross(b, c), n_ca = Cross(c, a), n_ab = Cross(a, b);
    const double volume = Dot(a, n_bc);  // d . (n_bc + n_ca + n_ab) t = this at the hit
    const double abs_volume = std::fabs(volume);
    for (int64_t cy = cy0; cy <= cy1; ++cy) {
      const int64_t first = start[cy * nx + cx0], last = start[cy * nx + cx1 + 1];
      for (int64_t i = first; i < last; i += kLanes) {
        const Lanes x = LoadLanes(&dx[i]), y = LoadLanes(&dy[i]), z = LoadLanes(&dz[i]);
        const Lanes wa = x * n_bc.x + y * n_bc.y + z * n_bc.z;
        const Lanes wb = x * n_ca.x + y * n_ca.y + z * n_ca.z;
        const Lanes wc = x * n_ab.x + y * n_ab.y + z * n_ab.z;
        const Lanes sum = wa + wb + wc;
        // Inside from either side, ahead of the eye (volume / sum > 0) and nearer than the
        // best so far, compared without dividing. sum = 0 is never nearer (0 < 0 fails).
        const Bits inside = ((wa >= zero) & (wb >= zero) & (wc >= zero)) |
                            ((wa <= zero) & (wb <= zero) & (wc <= zero));
        const Lanes old_volume = LoadLanes(&best_volume[i]), old_sum = LoadLanes(&best_sum[i]);
        const Lanes abs_sum = Abs(sum);
        const Bits take = inside & (volume * sum > zero) &
                          (abs_volume * old_sum < old_volume * abs_sum);
        StoreLanes(&best_volume[i], Select(take, abs_volume + zero, old_volume));
        StoreLanes(&best_sum[i], Select(take, abs_sum, old_sum));
        StoreLanes(&best_signed_sum[i], Select(take, sum, LoadLanes(&best_signed_sum[i])));
        StoreLanes(&best_wb[i], Select(take, wb, LoadLanes(&best_wb[i])));
        StoreLanes(&best_wc[i], Select(take, wc, LoadLanes(&best_wc[i])));
        Bits faces_so_far;
        std::memcpy(&faces_so_far, &best_face[i], sizeof faces_so_far);
        faces_so_far = (take & f) | (~take & faces_so_far);
        std::memcpy(&best_face[i], &faces_so_far, sizeof faces_so_far);
      }
    }
  }
  for (int64_t i = 0; i < slots; ++i) {
    const int64_t r = order[i];
    if (r < 0) continue;
    const bool hit = best_face[i] >= 0;
    face_out[r] = best_face[i];
    t_out[r] = hit ? best_volume[i] / best_sum[i] : std::numeric_limits<double>::infinity();
    u_out[r] = hit ? best_wb[i] / best_signed_sum[i] : 0.0;
    v_out[r] = hit ? best_wc[i] / best_signed_sum[i] : 0.0;
    if (corner_values == nullptr) continue;
    // The corners' values mixed by the clipped, renormalised barycentrics (as the Python
    // shading mixes embree's): (max(1 - u - v, 0), u, v) over their sum.
    const double u = u_out[r], v = v_out[r], w = std::max(1.0 - u - v, 0.0);
    const double total = w + u + v;
    const double* corners = corner_values + 3 * num_values * (hit ? best_face[i] : 0);
    for (int64_t k = 0; k < num_values; ++k) {
      values_out[r * num_values + k] =
          hit ? (w * corners[k] + u * corners[num_values + k] + v * corners[2 * num_values + k]) /
                    total
              : 0.0;
    }
  }
  return 0;
}
