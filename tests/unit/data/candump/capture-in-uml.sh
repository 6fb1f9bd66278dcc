#!/bin/sh
# Re-captures protocol_node0*.log: boots User-Mode Linux (DESIGN §8) with this script as
# init, sends protocol_node0.cansend with cansend and records candump -L and default output.
#   linux.uml mem=256M rootfstype=hostfs rootflags=/ rw con=null con0=fd:0,fd:1 \
#     init=$PWD/tests/unit/data/candump/capture-in-uml.sh
# (run from the repository root; the frames come from protocol::encode, see the README).
export PATH=/usr/sbin:/usr/bin:/sbin:/bin
DIR=$(dirname "$0")
mount -t proc proc /proc
mount -t sysfs sysfs /sys
M=/usr/lib/uml/modules/$(uname -r)/kernel
for m in net/can/can.ko net/can/can-raw.ko drivers/net/can/dev/can-dev.ko drivers/net/can/vcan.ko; do
  busybox insmod "$M/$m"
done
ip link add dev vcan0 type vcan
ip link set vcan0 mtu 72
ip link set up vcan0
candump -L vcan0 > "$DIR/protocol_node0.log" &
P1=$!
candump vcan0 > "$DIR/protocol_node0_default.log" &
P2=$!
sleep 1
while read -r f; do cansend vcan0 "$f"; done < "$DIR/protocol_node0.cansend"
sleep 1
kill $P1 $P2
sleep 1
sync
busybox poweroff -f
