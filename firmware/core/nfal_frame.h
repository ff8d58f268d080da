/* The frame's building blocks of the nfal rig protocol (docs/protocol.md section 2): CRC-32, COBS, the sequence
 * order. The rig's firmware (nfal_fw.h) and the host's compiled loop (../loop/nfal_loop.h) both build on them. */
#ifndef NFAL_FRAME_H
#define NFAL_FRAME_H

#include <stddef.h>
#include <stdint.h>

/* The building blocks, exposed for the unit tests and for a board's own use. */
uint32_t nfal_crc32(const uint8_t *p, size_t n);
size_t nfal_cobs_encode(const uint8_t *in, size_t n, uint8_t *out);
int nfal_cobs_decode(const uint8_t *in, size_t n, uint8_t *out);
int nfal_seq_newer(uint32_t seq, uint32_t last);

#endif
