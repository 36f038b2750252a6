/* A reference of the receiver of MotionCal's calibration packet, for tests/test_export_motioncal.py.
 *
 * receiveCalibration() and crc16_update() follow Adafruit_AHRS examples/calibration/calibration.ino
 * (the same receiver as PJRC NXPMotionSense examples/CalibrateSensors): the first byte must be 117,
 * the second 84, at 68 bytes the CRC-16 (0xFFFF, polynomial 0xA001) over all 68 must be 0, then the
 * sixteen little-endian floats are taken as offsets[0..15] and the soft iron is rebuilt with
 * mag_softiron[1] = offsets[13], [2] = offsets[14], [5] = offsets[15].  On a CRC failure the search
 * restarts at a later 117,84 or a final 117, as there.
 *
 * Reads bytes on stdin; for each packet accepted prints "accepted" and the 19 numbers the sketch then
 * holds (accel_zerog[3], gyro_zerorate[3], mag_hardiron[3], mag_field, mag_softiron[9]) with %.9g, one
 * line, then "stored" and the 68 bytes in hex that Adafruit_Sensor_Calibration_EEPROM::saveCalibration()
 * writes from those numbers (signature 0x75 0x54, offsets[16], CRC low byte first); prints "rejected N"
 * with the number of CRC failures at the end.  Needs a little-endian host
 * with 32-bit IEEE floats (as the sketches' memcpy does on their boards).
 */
#include <stdint.h>
#include <stdio.h>
#include <string.h>

static uint8_t caldata[68];
static uint8_t calcount = 0;
static int rejected = 0;

static uint16_t crc16_update(uint16_t crc, uint8_t a)
{
    int i;
    crc ^= a;
    for (i = 0; i < 8; i++) {
        if (crc & 1) {
            crc = (crc >> 1) ^ 0xA001;
        } else {
            crc = (crc >> 1);
        }
    }
    return crc;
}

/* Adafruit_Sensor_Calibration_EEPROM::saveCalibration(), into a buffer instead of the EEPROM. */
static void save(const float *zerog, const float *zerorate, const float *hardiron, float field, const float *softiron)
{
    uint8_t buf[68];
    float offsets[16];
    uint16_t crc = 0xFFFF;
    int i;

    memset(buf, 0, 68);
    buf[0] = 0x75;
    buf[1] = 0x54;
    memcpy(offsets, zerog, 12);
    memcpy(offsets + 3, zerorate, 12);
    memcpy(offsets + 6, hardiron, 12);
    offsets[9] = field;
    offsets[10] = softiron[0];
    offsets[11] = softiron[4];
    offsets[12] = softiron[8];
    offsets[13] = softiron[1];
    offsets[14] = softiron[2];
    offsets[15] = softiron[5];
    memcpy(buf + 2, offsets, 16 * 4);
    for (i = 0; i < 66; i++) crc = crc16_update(crc, buf[i]);
    buf[66] = crc & 0xFF;
    buf[67] = crc >> 8;
    printf("stored");
    for (i = 0; i < 68; i++) printf(" %02x", buf[i]);
    printf("\n");
}

static void take(uint8_t b)
{
    uint16_t crc;
    int i;
    float offsets[16], softiron[9];

    if (calcount == 0 && b != 117) return;
    if (calcount == 1 && b != 84) {
        calcount = 0;
        return;
    }
    caldata[calcount++] = b;
    if (calcount < 68) return;
    crc = 0xFFFF;
    for (i = 0; i < 68; i++) crc = crc16_update(crc, caldata[i]);
    if (crc == 0) {
        memcpy(offsets, caldata + 2, 16 * 4);
        softiron[0] = offsets[10]; softiron[1] = offsets[13]; softiron[2] = offsets[14];
        softiron[3] = offsets[13]; softiron[4] = offsets[11]; softiron[5] = offsets[15];
        softiron[6] = offsets[14]; softiron[7] = offsets[15]; softiron[8] = offsets[12];
        printf("accepted");
        for (i = 0; i < 10; i++) printf(" %.9g", offsets[i]);
        for (i = 0; i < 9; i++) printf(" %.9g", softiron[i]);
        printf("\n");
        save(offsets, offsets + 3, offsets + 6, offsets[9], softiron);
        calcount = 0;
        return;
    }
    rejected++;
    for (i = 2; i < 67; i++) {
        if (caldata[i] == 117 && caldata[i + 1] == 84) {
            calcount = 68 - i;
            memmove(caldata, caldata + i, calcount);
            return;
        }
    }
    if (caldata[67] == 117) {
        caldata[0] = 117;
        calcount = 1;
    } else {
        calcount = 0;
    }
}

int main(void)
{
    int c;
    while ((c = getchar()) != EOF) take((uint8_t)c);
    printf("rejected %d\n", rejected);
    return 0;
}
