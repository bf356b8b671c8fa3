#!/usr/bin/env python3
"""Re-make the window layout of rviz/multi_map_merge.rviz with rviz itself (not part of the tests).

rviz restores its panels from the ``QMainWindow State`` blob of ``Window Geometry``; without one
(rviz 1.14) every panel docks left and the map view is a strip. This loads the file in rviz
(python3-rviz bindings), keeps only the Displays panel docked left at its minimum width, hides
Selection, Tool Properties, Views (docked right) and Time (docked bottom): the Panels menu
brings them back; sizes the window, lets rviz save, and writes rviz's ``Window Geometry`` and
the Displays panel's tree height back into the file; the displays are left as written by hand.
Needs an X display and a ROS master:

    apt-get install python3-rviz xvfb
    roscore &  xvfb-run -s '-screen 0 1400x900x24' python3 tools/rviz_layout.py [file.rviz]
"""
import argparse
import os
import re
import sys
import tempfile

import yaml
from python_qt_binding.QtCore import Qt, QTimer
from python_qt_binding.QtWidgets import QApplication, QDockWidget

from rviz import bindings as rviz

ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument('file', nargs='?', default=os.path.join(os.path.dirname(__file__), '..', 'rviz',
                                                       'multi_map_merge.rviz'))
ap.add_argument('--width', type=int, default=1400)
ap.add_argument('--height', type=int, default=900)
a = ap.parse_args()

app = QApplication(sys.argv[:1])
frame = rviz.VisualizationFrame()
frame.setSplashPath('')
frame.initialize(a.file)
frame.move(0, 0)
frame.resize(a.width, a.height)
frame.show()
docks = {d.objectName(): d for d in frame.findChildren(QDockWidget)}
fd, saved = tempfile.mkstemp(suffix='.rviz')
os.close(fd)


def arrange():
    frame.addDockWidget(Qt.LeftDockWidgetArea, docks['Displays'])
    frame.addDockWidget(Qt.RightDockWidgetArea, docks['Views'])    # where they show when
    frame.addDockWidget(Qt.BottomDockWidgetArea, docks['Time'])    # brought back
    for name, dock in docks.items():
        if name != 'Displays':
            dock.hide()
    QTimer.singleShot(500, lambda: frame.resizeDocks([docks['Displays']], [1], Qt.Horizontal))
    QTimer.singleShot(1500, save)


def save():
    frame.saveDisplayConfig(saved)
    app.quit()


QTimer.singleShot(2000, arrange)
app.exec_()

with open(saved) as f:
    rviz_text = f.read()
os.unlink(saved)
geometry = rviz_text[rviz_text.index('\nWindow Geometry:\n') + 1:]
geometry = geometry.replace('Hide Right Dock: true', 'Hide Right Dock: false')  # nothing shows there
tree_height = yaml.safe_load(rviz_text)['Panels'][0]['Tree Height']
with open(a.file) as f:
    text = f.read()
text = text[:text.index('\nWindow Geometry:\n') + 1] if '\nWindow Geometry:\n' in text else text
text = re.sub(r'(\n    Tree Height: )\d+', r'\g<1>%d' % tree_height, text, count=1) + geometry
with open(a.file, 'w') as f:
    f.write(text)
central = frame.centralWidget().geometry()
print('%s: window %dx%d, 3D view %dx%d at (%d, %d)' % (a.file, a.width, a.height, central.width(),
                                                      central.height(), central.x(), central.y()))
