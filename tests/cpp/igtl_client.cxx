// A small OpenIGTLink client on the OpenIGTLink C++ library (built by tests/test_live_igtl_cpp.py):
// connects, sends GET_STATUS (header version 1, as this library writes), optionally asks for TDATA (STT_TDATA with a resolution in ms), and prints one line per
// message received, with the header's time stamp as raw seconds and 2^-32 fractions:
//   TRANSFORM <device> <sec> <frac> <12 values: the upper 3x4, row by row>
//   STRING <device> <sec> <frac> <text>
//   STATUS <device> <sec> <frac> <code> <subcode> <text>
//   TDATA <device> <sec> <frac> <n> then per tool: <name> <type> <12 values>
//   RTS_TDATA <device> <sec> <frac> <status>
//   OTHER <type> <device>            (skipped unread)
//   CRCFAIL <type> <device>          (the library's CRC check failed)
// Usage: igtl_client HOST PORT SECONDS [STT_TDATA_RESOLUTION_MS]
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>

#include "igtlClientSocket.h"
#include "igtlMessageHeader.h"
#include "igtlStatusMessage.h"
#include "igtlStringMessage.h"
#include "igtlTrackingDataMessage.h"
#include "igtlTransformMessage.h"

static void print_matrix(igtl::Matrix4x4 &m) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) std::printf(" %.9g", m[r][c]);
}

int main(int argc, char **argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: %s HOST PORT SECONDS [STT_TDATA_MS]\n", argv[0]);
    return 2;
  }
  igtl::ClientSocket::Pointer sock = igtl::ClientSocket::New();
  if (sock->ConnectToServer(argv[1], std::atoi(argv[2])) != 0) {
    std::fprintf(stderr, "cannot connect to %s:%s\n", argv[1], argv[2]);
    return 1;
  }
  sock->SetReceiveTimeout(200);
  igtl::GetStatusMessage::Pointer get = igtl::GetStatusMessage::New();   // answered by STATUS
  get->SetDeviceName("Client");
  get->Pack();
  sock->Send(get->GetPackPointer(), get->GetPackSize());
  if (argc > 4) {
    igtl::StartTrackingDataMessage::Pointer stt = igtl::StartTrackingDataMessage::New();
    stt->SetDeviceName("Tracker");
    stt->SetResolution(std::atoi(argv[4]));
    stt->SetCoordinateName("Tracker");
    stt->Pack();
    sock->Send(stt->GetPackPointer(), stt->GetPackSize());
  }
  std::printf("CONNECTED\n");
  std::fflush(stdout);
  const time_t end = std::time(NULL) + std::atoi(argv[3]);
  igtl::MessageHeader::Pointer head = igtl::MessageHeader::New();
  while (std::time(NULL) < end) {
    head->InitPack();
    int r = sock->Receive(head->GetPackPointer(), head->GetPackSize());
    if (r == 0) break;                       // closed (or timed out: try again)
    if (r != head->GetPackSize()) continue;
    head->Unpack();
    unsigned int sec = 0, frac = 0;
    head->GetTimeStamp(&sec, &frac);
    const char *type = head->GetDeviceType();
    const char *dev = head->GetDeviceName();
    igtl::MessageBase::Pointer msg;
    if (!std::strcmp(type, "TRANSFORM")) msg = igtl::TransformMessage::New();
    else if (!std::strcmp(type, "STRING")) msg = igtl::StringMessage::New();
    else if (!std::strcmp(type, "STATUS")) msg = igtl::StatusMessage::New();
    else if (!std::strcmp(type, "TDATA")) msg = igtl::TrackingDataMessage::New();
    else if (!std::strcmp(type, "RTS_TDATA")) msg = igtl::RTSTrackingDataMessage::New();
    if (msg.IsNull()) {
      std::printf("OTHER %s %s\n", type, dev);
      sock->Skip(head->GetBodySizeToRead(), 0);
      continue;
    }
    msg->SetMessageHeader(head);
    msg->AllocatePack();
    sock->Receive(msg->GetPackBodyPointer(), msg->GetPackBodySize());
    if (!(msg->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) {
      std::printf("CRCFAIL %s %s\n", type, dev);
      continue;
    }
    std::printf("%s %s %u %u", type, dev, sec, frac);
    if (!std::strcmp(type, "TRANSFORM")) {
      igtl::Matrix4x4 m;
      static_cast<igtl::TransformMessage *>(msg.GetPointer())->GetMatrix(m);
      print_matrix(m);
    } else if (!std::strcmp(type, "STRING")) {
      std::printf(" %s", static_cast<igtl::StringMessage *>(msg.GetPointer())->GetString());
    } else if (!std::strcmp(type, "STATUS")) {
      igtl::StatusMessage *s = static_cast<igtl::StatusMessage *>(msg.GetPointer());
      std::printf(" %d %lld %s", s->GetCode(), (long long)s->GetSubCode(), s->GetStatusString());
    } else if (!std::strcmp(type, "TDATA")) {
      igtl::TrackingDataMessage *t = static_cast<igtl::TrackingDataMessage *>(msg.GetPointer());
      int n = t->GetNumberOfTrackingDataElements();
      std::printf(" %d", n);
      for (int i = 0; i < n; ++i) {
        igtl::TrackingDataElement::Pointer e;
        t->GetTrackingDataElement(i, e);
        igtl::Matrix4x4 m;
        e->GetMatrix(m);
        std::printf(" %s %d", e->GetName(), (int)e->GetType());
        print_matrix(m);
      }
    } else if (!std::strcmp(type, "RTS_TDATA")) {
      std::printf(" %d",
                  (int)static_cast<igtl::RTSTrackingDataMessage *>(msg.GetPointer())->GetStatus());
    }
    std::printf("\n");
    std::fflush(stdout);
  }
  sock->CloseSocket();
  return 0;
}
