// A reference-pose server on the OpenIGTLink C++ library (built by
// tests/test_collect_cpp_reference.py): it replays a motion file as TRANSFORM messages
// (header version 1, as this library writes) of one device to every connected client.
//
// Motion file: plain text, one pose per line, '#' lines skipped:
//   t x_mm y_mm z_mm r00 r01 r02 r10 r11 r12 r20 r21 r22
// t: seconds of the motion (increasing, from 0); x, y, z: translation (mm); rij: rotation,
// row by row. The motion's clock starts when the first client connects (wall time T0); the
// pose of time t is sent at wall time T0 + t / SPEED and stamped T0 + t (the motion's own
// clock, SPEED times faster than the wall's). After the last line the last pose is sent
// again every 10 ms of wall time for HOLD_S seconds, stamped on, then the server exits.
// It prints "PORT <port>" once listening and "DONE <messages sent>" at the end.
//
// Usage: igtl_reference_server MOTION_FILE DEVICE [PORT=0] [SPEED=1] [HOLD_S=3]
//        [WAIT_S=60: give up when no client connects within this many seconds]
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <sys/time.h>
#include <unistd.h>
#include <vector>

#include "igtlServerSocket.h"
#include "igtlTimeStamp.h"
#include "igtlTransformMessage.h"

struct Pose { double t; float m[12]; };

static double now() {
  struct timeval tv;
  gettimeofday(&tv, NULL);
  return tv.tv_sec + 1e-6 * tv.tv_usec;
}

static void sleep_until(double when) {
  double d = when - now();
  if (d > 0) usleep(static_cast<useconds_t>(d * 1e6));
}

int main(int argc, char **argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s MOTION_FILE DEVICE [PORT] [SPEED] [HOLD_S] [WAIT_S]\n",
                 argv[0]);
    return 2;
  }
  std::signal(SIGPIPE, SIG_IGN);           // a client gone: Send fails, the client is dropped
  const int port = argc > 3 ? std::atoi(argv[3]) : 0;
  const double speed = argc > 4 ? std::atof(argv[4]) : 1.0;
  const double hold = argc > 5 ? std::atof(argv[5]) : 3.0;
  const double wait = argc > 6 ? std::atof(argv[6]) : 60.0;
  std::vector<Pose> poses;
  std::ifstream in(argv[1]);
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    double v[13];
    int n = 0;
    while (n < 13 && s >> v[n]) ++n;
    if (n != 13 || (!poses.empty() && v[0] <= poses.back().t)) {
      std::fprintf(stderr, "expected 13 numbers with increasing t per line, got: %s\n",
                   line.c_str());
      return 2;
    }
    Pose p;
    p.t = v[0];
    const int order[12] = {4, 5, 6, 1, 7, 8, 9, 2, 10, 11, 12, 3};   // rows [r | t]
    for (int k = 0; k < 12; ++k) p.m[k] = static_cast<float>(v[order[k]]);
    poses.push_back(p);
  }
  if (poses.empty() || speed <= 0) {
    std::fprintf(stderr, "expected a motion file with poses and SPEED > 0\n");
    return 2;
  }
  igtl::ServerSocket::Pointer server = igtl::ServerSocket::New();
  if (server->CreateServer(port) < 0) {
    std::fprintf(stderr, "cannot listen on port %d\n", port);
    return 1;
  }
  std::printf("PORT %d\n", server->GetServerPort());
  std::fflush(stdout);
  std::vector<igtl::ClientSocket::Pointer> clients;
  const double give_up = now() + wait;
  while (clients.empty()) {
    igtl::ClientSocket::Pointer c = server->WaitForConnection(100);
    if (c.IsNotNull()) clients.push_back(c);
    else if (now() > give_up) { std::fprintf(stderr, "no client connected\n"); return 1; }
  }
  const double t0 = now();
  igtl::TransformMessage::Pointer msg = igtl::TransformMessage::New();
  msg->SetDeviceName(argv[2]);
  igtl::TimeStamp::Pointer ts = igtl::TimeStamp::New();
  long sent = 0;
  double accepted = t0;
  const size_t n = poses.size();
  const double t_end = poses.back().t + hold * speed;
  for (size_t k = 0;; ++k) {
    const Pose &p = poses[k < n ? k : n - 1];
    const double t = k < n ? p.t : poses.back().t + (k - n + 1) * 0.01 * speed;
    if (t > t_end) break;
    sleep_until(t0 + t / speed);
    if (now() - accepted > 0.05) {          // more clients, every 50 ms
      accepted = now();
      igtl::ClientSocket::Pointer c = server->WaitForConnection(1);
      if (c.IsNotNull()) clients.push_back(c);
    }
    igtl::Matrix4x4 m;
    igtl::IdentityMatrix(m);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) m[r][c] = p.m[4 * r + c];
    msg->SetMatrix(m);
    ts->SetTime(t0 + t);
    msg->SetTimeStamp(ts);
    msg->Pack();
    for (size_t i = 0; i < clients.size();) {
      if (clients[i]->Send(msg->GetPackPointer(), msg->GetPackSize()) == 1) { ++i; ++sent; }
      else clients.erase(clients.begin() + i);
    }
  }
  for (size_t i = 0; i < clients.size(); ++i) clients[i]->CloseSocket();
  server->CloseSocket();
  std::printf("DONE %ld\n", sent);
  return 0;
}
