#include "flashtwin/sim/mujoco_handles.hpp"

#include <cstring>
#include <mutex>

#include "flashtwin/core/errors.hpp"

namespace flashtwin::sim {

namespace {
// MuJoCo 2.2's XML parser and compiler keep global state: one model load at a time (parallel
// sweeps load models from several threads).
std::mutex& load_mutex() {
  static std::mutex m;
  return m;
}
}  // namespace

MjModelPtr load_mjcf_file(const std::string& path) {
  char err[1024] = "";
  mjModel* m = nullptr;
  {
    const std::lock_guard<std::mutex> lock(load_mutex());
    m = mj_loadXML(path.c_str(), nullptr, err, sizeof err);
  }
  if (!m) throw InputError(path + ": MuJoCo cannot load the model: " + err);
  return MjModelPtr(m);
}

MjModelPtr load_mjcf_string(const std::string& xml, const std::string& name) {
  // mjVFS holds fixed-size name tables (megabytes): keep it on the heap.
  auto vfs = std::make_unique<mjVFS>();
  mj_defaultVFS(vfs.get());
  if (mj_makeEmptyFileVFS(vfs.get(), name.c_str(), static_cast<int>(xml.size())) != 0)
    throw InputError(name + ": cannot place the model in MuJoCo's virtual file system");
  const int id = mj_findFileVFS(vfs.get(), name.c_str());
  std::memcpy(vfs->filedata[id], xml.data(), xml.size());
  char err[1024] = "";
  mjModel* m = nullptr;
  {
    const std::lock_guard<std::mutex> lock(load_mutex());
    m = mj_loadXML(name.c_str(), vfs.get(), err, sizeof err);
  }
  mj_deleteVFS(vfs.get());
  if (!m) throw InputError(name + ": MuJoCo cannot load the model: " + err);
  return MjModelPtr(m);
}

MjDataPtr make_data(const mjModel* m) { return MjDataPtr(mj_makeData(m)); }

int require_id(const mjModel* m, mjtObj type, const std::string& name) {
  const int id = mj_name2id(m, type, name.c_str());
  if (id < 0) throw InputError("model: expected an object named '" + name + "', found none");
  return id;
}

void rigid_inverse_dynamics(const mjModel* m, mjData* d, mjtNum* tau) {
  mj_kinematics(m, d);
  mj_comPos(m, d);
  mj_comVel(m, d);  // cvel, cdof_dot (needs comPos)
  mj_passive(m, d);
  mj_rne(m, d, 1, tau);  // M_body·q̈ + bias; the armature is not a body inertia, added below
  for (int i = 0; i < m->nv; ++i) tau[i] += m->dof_armature[i] * d->qacc[i] - d->qfrc_passive[i];
}

}  // namespace flashtwin::sim
