#include "flashtwin/core/subprocess.hpp"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "flashtwin/core/errors.hpp"

extern char** environ;

namespace flashtwin {

PipedProcess::PipedProcess(const std::vector<std::string>& argv) {
  FT_ASSERT(!argv.empty());
  // O_CLOEXEC: the write end must not leak into this or any other child, or the child would
  // never see the end of its input.
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0)
    throw IoError(argv[0] + ": cannot create a pipe (" + std::strerror(errno) + ")");
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, fds[0], STDIN_FILENO);  // dup2 clears CLOEXEC
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  const int rc = ::posix_spawnp(&pid_, argv[0].c_str(), &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(fds[0]);
  if (rc != 0) {
    ::close(fds[1]);
    pid_ = -1;
    throw IoError(argv[0] + ": cannot start the program (" + std::strerror(rc) +
                  "; is it installed and in PATH?)");
  }
  fd_ = fds[1];
}

PipedProcess::~PipedProcess() {
  finish();
}

bool PipedProcess::write(const void* data, std::size_t n) {
  if (fd_ < 0) return false;
  // A write to a pipe whose reader is gone raises SIGPIPE, whose default action ends this
  // process. Block it in this thread for the write and discard the one it may leave pending.
  sigset_t pipe_only, old;
  sigemptyset(&pipe_only);
  sigaddset(&pipe_only, SIGPIPE);
  pthread_sigmask(SIG_BLOCK, &pipe_only, &old);
  const char* p = static_cast<const char*>(data);
  bool ok = true;
  while (n > 0) {
    const ssize_t w = ::write(fd_, p, n);
    if (w < 0) {
      if (errno == EINTR) continue;
      ok = false;  // EPIPE: the child stopped reading
      break;
    }
    p += w;
    n -= static_cast<std::size_t>(w);
  }
  if (!ok) {
    const timespec zero{0, 0};
    while (sigtimedwait(&pipe_only, nullptr, &zero) == SIGPIPE) {
    }
  }
  pthread_sigmask(SIG_SETMASK, &old, nullptr);
  return ok;
}

int PipedProcess::finish() {
  if (fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
  if (pid_ > 0) {
    int st = 0;
    pid_t r;
    do r = ::waitpid(pid_, &st, 0);
    while (r < 0 && errno == EINTR);
    pid_ = -1;
    if (r < 0)
      status_ = 127;
    else
      status_ = WIFEXITED(st) ? WEXITSTATUS(st) : WIFSIGNALED(st) ? 128 + WTERMSIG(st) : 127;
  }
  return status_;
}

}  // namespace flashtwin
