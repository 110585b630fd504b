#pragma once
// RAII owners of MuJoCo's C handles. Only sim/ and its tests include this (DESIGN.md: only sim
// sees MuJoCo).
#include <mujoco/mujoco.h>

#include <memory>
#include <string>

namespace flashtwin::sim {

struct MjModelDeleter {
  void operator()(mjModel* m) const { mj_deleteModel(m); }
};
struct MjDataDeleter {
  void operator()(mjData* d) const { mj_deleteData(d); }
};
using MjModelPtr = std::unique_ptr<mjModel, MjModelDeleter>;
using MjDataPtr = std::unique_ptr<mjData, MjDataDeleter>;

/// Compiles an MJCF file. @throws InputError "<path>: MuJoCo: <message>".
MjModelPtr load_mjcf_file(const std::string& path);

/// Compiles MJCF text held in memory (tests, generated cells); `name` appears in errors.
MjModelPtr load_mjcf_string(const std::string& xml, const std::string& name = "model.xml");

/// Fresh mjData for a model.
MjDataPtr make_data(const mjModel* m);

/// Rigid-body inverse dynamics τ = M(q)·q̈ + c(q, q̇) − passive(q, q̇) (armature included) for
/// d's qpos, qvel and qacc: what mj_inverse gives with contacts and constraints disabled, without
/// its camera, tendon, mass-matrix and sensor passes (a third of its time on the arm). Writes
/// d's kinematics, velocities and qfrc_passive; tau has m->nv entries.
void rigid_inverse_dynamics(const mjModel* m, mjData* d, mjtNum* tau);

/// Id of a named object or throws InputError naming what was expected.
int require_id(const mjModel* m, mjtObj type, const std::string& name);

}  // namespace flashtwin::sim
